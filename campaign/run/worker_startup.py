"""The worker plug-ins that tune each dask worker process for cases as it starts and hand it the inputs the
driver loaded already.

Kept apart from :mod:`campaign.run.worker` on purpose: a worker imports this module to run the plug-ins
when it starts (or the inputs arrive), and it needs only ctypes and OpenCV (0.2 s,
:mod:`campaign.case.process_tuning`), not the simulator and the estimators (5 s), which a worker loads with
its first case anyway; the cluster's start waits for the plug-ins.
"""
from __future__ import annotations

import importlib
import threading

from distributed import WorkerPlugin

from campaign.case import shipped_inputs
from campaign.case.process_tuning import tune_once

#: the module of the case tasks (and with it the simulator and the estimators), imported ahead of the first task
CASE_MODULE = "campaign.run.worker"


class CaseWorkerSetup(WorkerPlugin):
    """Tunes each worker process as it starts (:func:`~campaign.case.process_tuning.tune_process`), before any task runs on it: plug-in
    checks and estimator set-up run single-threaded too, not only the cases (which tune on first use).

    Then imports the case code (:data:`CASE_MODULE`, 1.2-1.8 s of CPU) in a thread of its own, while the driver
    still prepares the run (ships the plug-ins' code and the inputs it loaded, prepares the stores): the first
    task finds it imported (or waits on Python's import lock for the rest) instead of starting it. A failing
    import is left to the first task, which reports it as before."""

    name = "moc2dimes-case-worker"

    def setup(self, worker) -> None:
        tune_once()
        threading.Thread(target=_import_quietly, args=(CASE_MODULE,), daemon=True,
                         name="moc2dimes-case-imports").start()


def _import_quietly(module: str) -> None:
    try:
        importlib.import_module(module)
    except ImportError:     # the first task imports it again and reports the error as a task's
        pass


class ShippedInputs(WorkerPlugin):
    """Inputs the driver loaded that every worker would load alike (:func:`campaign.case.inputs.shippable_inputs`, pickled):
    kept as they arrive, unpickled by the worker's first case (:mod:`campaign.case.shipped_inputs`)."""

    name = "moc2dimes-shipped-inputs"

    def __init__(self, payload: bytes):
        self.payload = payload

    def setup(self, worker) -> None:
        shipped_inputs.receive(self.payload)
        self.payload = b""          # the worker keeps its plug-ins: the bytes live in shipped_inputs until taken
