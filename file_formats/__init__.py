"""File formats, at the bottom of the project: every file a campaign, the simulator or an estimator reads or writes.

* :mod:`file_formats.planetary`         orbital and descent images in planetary formats: PDS3, ISIS3, VICAR,
                                        MSSS DDD, PNG/TIFF rasters, and the side-car TOML that completes them;
* :mod:`file_formats.descent_images`    descent image files -> the binned camera DN an estimator takes;
* :mod:`file_formats.measurements_json` the measurements file (what the flight system measured per image);
* :mod:`file_formats.flat_field_files`  flat-field calibration files (.npy, TIFF, FITS);
* :mod:`file_formats.errors`            the one-line error of an unusable input file.

Imports only :mod:`flight_interface` (the record types the files hold); used by the simulator side, the
estimator side and the campaign alike.
"""
