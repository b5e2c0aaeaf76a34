"""Minimal estimator plug-ins to copy: one of each kind (docs/estimators.md, "The contract, field by field").

:mod:`estimators.examples.minimal_python` (``kind = "python"``) and :mod:`estimators.examples.minimal_command`
(``kind = "command"``, a stand-alone script) give the same answer on the same case. Both import only numpy
and the standard library, so a copy works outside this project.
"""
