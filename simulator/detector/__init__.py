"""Detector stages (Pyxel-style): from radiance at the aperture to 12-bit DN.

Read in this order: ``optics`` (photon collection: responsivity, cos^4 falloff) ->
``charge_generation`` (PRNU, dark current) -> ``charge_transfer`` (flush / exposure / transfer smear,
on-chip binning) -> ``blooming`` (charge above full well) -> ``readout`` (shot and read noise, gain,
offset, 12-bit ADC); ``psf`` (the optics' blur); ``camera_chain`` composes them as an ordered list of
stage functions (``CHARGE_STAGES``, then ``read_out``).
"""
