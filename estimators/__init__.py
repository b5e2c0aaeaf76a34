"""Velocity estimators behind one contract, so a campaign can run and compare any of them.

* :mod:`estimators.contract`          the contract: inputs, output, violations (read this first);
* :mod:`estimators.entries`           ``[[estimators]]`` entries -> validated specs;
* :mod:`estimators.plugins`           specs -> estimator objects; running one on a case, failures caught;
* :mod:`estimators.command`           external programs (a compiled flight estimator runs unchanged);
* :mod:`estimators.run_python`        a Python callable run in its own process (``isolate = true``);
* :mod:`estimators.phase_correlation` example: whole-image phase correlation of rectified images.

Like :mod:`dimes_velocity`, this package imports nothing from :mod:`simulator` or :mod:`campaign`.
"""
from estimators.contract import ContractViolation, EstimatorInputs, EstimatorOutput, validate_output

__all__ = ["ContractViolation", "EstimatorInputs", "EstimatorOutput", "validate_output"]
