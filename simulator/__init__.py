"""MOC2DIMES descent camera simulator: from orbital terrain to descent-camera DN.

The listing reads from terrain to DN:

1. :mod:`simulator.scene`        descent pose, terrain, ground mapping, photometry, shadows, heat shield
                                 and its glint, motion blur -> radiance fields per CCD period;
2. :mod:`simulator.off_nominal`  dust, hot pixels, particle hits (drawn per case), switches;
3. :mod:`simulator.detector`     optics, charge generation, charge transfer, blooming, readout -> DN;
4. :mod:`simulator.descent_image` composes 1-3 for one image; :mod:`simulator.scene_config` holds its
   configuration and :mod:`simulator.fidelity` the presets of documented shortcuts;
5. :mod:`simulator.sensors`      the measurement error models (attitude, radar, IMU) that turn the true
                                 trajectory into what the estimator is given;
6. :mod:`simulator.calibration`  simulated ground flat-field calibration; :mod:`simulator.fields` the field
                                 types both stages share; :mod:`simulator.scratch` per-thread work arrays;
                                 :mod:`simulator.derived_cache` arrays derived from a camera or terrain.

The camera model itself (CAHVOR, camera file, frames) is shared with the estimator and lives in
:mod:`flight_interface`. ``python -m simulator.render_example --out DIR`` renders an example descent.
"""
