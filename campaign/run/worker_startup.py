"""The worker plug-ins that tune each dask worker process for cases as it starts and hand it the inputs the
driver loaded already.

Kept apart from :mod:`campaign.run.worker` on purpose: a worker imports this module to run the plug-ins
when it starts (or the inputs arrive), and it needs only ctypes and OpenCV (0.2 s,
:mod:`campaign.case.process_tuning`), not the simulator and the estimators (5 s), which a worker loads with
its first case anyway; the cluster's start waits for the plug-ins.
"""
from __future__ import annotations

from distributed import WorkerPlugin

from campaign.case import shipped_inputs
from campaign.case.process_tuning import tune_once


class CaseWorkerSetup(WorkerPlugin):
    """Tunes each worker process as it starts (:func:`~campaign.case.process_tuning.tune_process`), before any task runs on it: plug-in
    checks and estimator set-up run single-threaded too, not only the cases (which tune on first use).

    The case code is imported by the first task, not ahead of it in a thread of its own: a task deserialised
    while another thread is importing the same packages can meet a partly initialised module (seen once as
    "Error during deserialization of the task graph" on a loaded machine), for ~1 s of start-up that the
    measurements could not tell from the noise."""

    name = "moc2dimes-case-worker"

    def setup(self, worker) -> None:
        tune_once()


class ShippedInputs(WorkerPlugin):
    """Inputs the driver loaded that every worker would load alike (:func:`campaign.case.inputs.shippable_inputs`, pickled):
    kept as they arrive, unpickled by the worker's first case (:mod:`campaign.case.shipped_inputs`)."""

    name = "moc2dimes-shipped-inputs"

    def __init__(self, payload: bytes):
        self.payload = payload

    def setup(self, worker) -> None:
        shipped_inputs.receive(self.payload)
        self.payload = b""          # the worker keeps its plug-ins: the bytes live in shipped_inputs until taken
