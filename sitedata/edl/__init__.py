"""EDL descent profiles (the stand-in for the ADAMS runs): equations of motion (:mod:`.dynamics`), the
generator and its parameter files, trajectory files (Parquet/CSV, POST tables), and
``python -m sitedata.edl.trajectory_sets``."""
