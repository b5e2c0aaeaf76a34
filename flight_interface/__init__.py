"""What a flight system and the simulator legitimately share, and nothing else.

Both :mod:`simulator` (which makes descent images) and :mod:`dimes_velocity` (the estimator under test,
which must never see the simulator's truth) import from here:

* :mod:`flight_interface.cahvor`       Gennery CAHVOR(E) projection with radial distortion;
* :mod:`flight_interface.calibration`  calibration products (the measured flat field) and their files;
* :mod:`flight_interface.camera_file`  the camera file (TOML): its tables, validated;
* :mod:`flight_interface.camera`       a validated file -> the runtime :class:`~flight_interface.camera.Camera`
                                       (geometry, timing, radiometry and electronics as designed);
* :mod:`flight_interface.frames`       world / body / camera frames and (w, x, y, z) quaternions;
* :mod:`flight_interface.measurements` the measurement record an estimator receives (measured attitude,
                                       radar altitude, IMU velocity per image).

Its tables are validated with :mod:`config_tables` (the bottom package: TOML reading, one-line errors).
"""
