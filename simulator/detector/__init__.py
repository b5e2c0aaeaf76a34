"""Detector stages (Pyxel-style): from radiance at the aperture to 12-bit DN.

Read in this order: ``optics`` (photon collection: responsivity, cos^4 falloff) ->
``charge_generation`` (PRNU, dark current) -> ``charge_transfer`` (flush / exposure / transfer smear,
on-chip binning) -> ``blooming`` (charge above full well) -> ``readout`` (shot and read noise, gain,
offset, 12-bit ADC); ``camera_chain`` composes them.
"""
