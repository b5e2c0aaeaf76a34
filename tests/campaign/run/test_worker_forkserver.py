"""The embedded cluster's workers are forked from a fork server that has imported the case code once
(campaign.run.cluster.start_worker_forkserver): a worker has the simulator, estimators and store modules
before its first task, still ignores the stop signals sent to the process group, and sees the driver's
environment of its run (the server started again when it changed, or, while workers forked from it still
run, the new workers spawned as before)."""
from __future__ import annotations

import os
import signal
import sys

import pytest

from campaign.configuration.execution import ExecutionConfig
from campaign.run.cluster import WORKER_FORKSERVER_PRELOAD, connected_client, start_worker_forkserver
from campaign.run.interrupts import STOP_SIGNALS

STOP_SIGNALS_NAMES = sorted(signal.Signals(number).name for number in STOP_SIGNALS)

pytestmark = pytest.mark.cluster


def _modules_and_marker(dask_worker) -> tuple[bool, str | None, list[str]]:
    """(the case code imported, the marker variable, the blocked stop signals) of this worker process."""
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, [])
    return ("campaign.run.worker" in sys.modules, os.environ.get("M2D_FORKSERVER_TEST_MARKER"),
            sorted(signal.Signals(number).name for number in blocked if number in STOP_SIGNALS))


def test_workers_forked_with_the_case_code_and_the_stop_signals_blocked():
    assert start_worker_forkserver()
    assert "campaign.run.worker" in WORKER_FORKSERVER_PRELOAD
    with connected_client(ExecutionConfig(workers=2), quiet=True) as client:
        states = list(client.run(_modules_and_marker).values())
    assert len(states) == 2
    for imported, marker, blocked in states:
        assert imported                      # before any task: forked from the server that imported it
        assert marker is None
        assert blocked == STOP_SIGNALS_NAMES


def test_a_changed_environment_reaches_the_workers(monkeypatch):
    assert start_worker_forkserver()        # the server runs, with this environment
    monkeypatch.setenv("M2D_FORKSERVER_TEST_MARKER", "changed after the server started")
    with connected_client(ExecutionConfig(workers=1), quiet=True) as client:
        # no other forked worker runs: the server is started again, with the new environment
        [(imported, marker, blocked)] = client.run(_modules_and_marker).values()
        assert imported and marker == "changed after the server started" and blocked == STOP_SIGNALS_NAMES
        monkeypatch.setenv("M2D_FORKSERVER_TEST_MARKER", "changed while forked workers run")
        with connected_client(ExecutionConfig(workers=1), quiet=True) as other:
            # the server cannot be replaced under running workers: this cluster's worker is spawned
            [(imported, marker, blocked)] = other.run(_modules_and_marker).values()
        assert not imported and marker == "changed while forked workers run" and blocked == STOP_SIGNALS_NAMES
    assert start_worker_forkserver()        # no forked worker left: the server started again
