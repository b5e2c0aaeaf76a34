"""Studies that run cases or whole campaigns and read them back: the flight-contrast calibration of the
terrain, the template-decorrelation ablation, the flight-like estimator's tuning, the error statistic's
readings. They sit at the top of ``campaign`` (beside the command line) because they use both the run
path and the reports; each has a ``python -m campaign.studies.<name>`` entry point (``template_correlation``
is the decorrelation study's per-template measurement, not a command)."""
