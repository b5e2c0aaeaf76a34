"""Reference DIMES (Descent Image Motion Estimation System) velocity estimator."""
