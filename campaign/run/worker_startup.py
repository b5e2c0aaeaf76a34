"""The worker plug-in that tunes each dask worker process for cases as it starts.

Kept apart from :mod:`campaign.run.worker` on purpose: a worker imports this module to run the plug-in
when it starts, and it needs only ctypes and OpenCV (0.2 s, :mod:`campaign.case.process_tuning`), not the
simulator and the estimators (5 s), which a worker loads with its first case anyway; the cluster's start
waits for the plug-in.
"""
from __future__ import annotations

from distributed import WorkerPlugin

from campaign.case.process_tuning import tune_once


class CaseWorkerSetup(WorkerPlugin):
    """Tunes each worker process as it starts (:func:`~campaign.case.process_tuning.tune_process`), before any task runs on it: plug-in
    checks and estimator set-up run single-threaded too, not only the cases (which tune on first use)."""

    name = "moc2dimes-case-worker"

    def setup(self, worker) -> None:
        tune_once()
