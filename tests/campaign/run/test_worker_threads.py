"""A campaign worker process runs one thread of computation (BLAS, OpenCV and dask's profiler checked inside
a real worker of the embedded cluster, before it has run any case), and pays for the campaign's context
once, not once per task."""
from __future__ import annotations

import dask
import pytest

from campaign.configuration.execution import ExecutionConfig
from campaign.run.cluster import WORKER_ENVIRONMENT, connected_client
from config_tables.models import parse


def _thread_settings(dask_worker) -> dict:
    """What limits the threads of this worker process (run inside it)."""
    import os

    import cv2
    import dask
    import threadpoolctl

    return {"opencv_threads": cv2.getNumThreads(),
            "blas_threads": sorted({pool["num_threads"] for pool in threadpoolctl.threadpool_info()}),
            "environment": {name: os.environ.get(name) for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                                                                     "MKL_NUM_THREADS")},
            "profiler_config": dask.config.get("distributed.worker.profile.enabled"),
            "profiler_callbacks": sorted(name for name in dask_worker.periodic_callbacks if "profile" in name),
            "dask_threads": dask_worker.state.nthreads,
            "housekeeping_ms": {name: dask_worker.periodic_callbacks[name].callback_time
                                for name in ("tick", "monitor", "memory_monitor")}}


@pytest.mark.cluster
def test_embedded_worker_is_single_threaded_before_its_first_case():
    with connected_client(ExecutionConfig(workers=1), quiet=True) as client:
        [settings] = client.run(_thread_settings).values()
    assert settings["opencv_threads"] == 1
    assert settings["blas_threads"] == [1]            # every BLAS / OpenMP pool numpy and OpenCV loaded
    assert settings["environment"] == {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    assert settings["profiler_config"] is False and settings["profiler_callbacks"] == []
    assert settings["dask_threads"] == 1
    # dask's housekeeping wakes the worker seldom (cluster.HOUSEKEEPING_DASK_CONFIG), its memory limit still watched
    assert settings["housekeeping_ms"] == {"tick": 1000, "monitor": 2000, "memory_monitor": 250}


def test_workers_started_elsewhere_get_the_same_settings():
    # dask reads DASK_* variables as configuration: the job scripts' and pods' environment turns the profiler off
    assert dask.config.collect_env(WORKER_ENVIRONMENT)["distributed"]["worker"]["profile"]["enabled"] is False
    from campaign.run.cluster import kubernetes_cluster_spec

    execution = parse(ExecutionConfig, {"cluster": "kubernetes", "kubernetes": {"image": "x"}}, "campaign.toml",
                      prefix="execution")
    [container] = kubernetes_cluster_spec(execution)["spec"]["worker"]["spec"]["containers"]
    assert {"name": "DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED", "value": "False"} in container["env"]
    assert {"name": "OMP_NUM_THREADS", "value": "1"} in container["env"]


def test_a_task_context_is_unpickled_once_per_process(tmp_path):
    """Every task carries the campaign's context; a worker rebuilds it on the first task only."""
    import pickle

    from campaign.configuration.campaign_file import load_campaign_config
    from campaign.run.worker import CampaignContext
    from service_campaigns import REPO

    config = load_campaign_config(REPO / "sitedata" / "gusev.toml", output_dir=tmp_path / "gusev")
    context = CampaignContext.from_config(config, tmp_path / "gusev")
    first, second = (pickle.loads(pickle.dumps(context)) for _ in range(2))   # two tasks' copies
    assert first is second
    assert first == context and first.config.config_hash == config.config_hash
    other = pickle.loads(pickle.dumps(CampaignContext.from_config(config, tmp_path / "elsewhere")))
    assert other is not first and other.store_root == str(tmp_path / "elsewhere")
    # a sweep's points each bring a context: a process keeps only the most recent ones
    from campaign.run import worker

    for index in range(worker.MAX_CONTEXTS + 8):
        pickle.loads(pickle.dumps(CampaignContext.from_config(config, tmp_path / f"point-{index}")))
    assert len(worker._CONTEXTS) == worker.MAX_CONTEXTS
    recent = pickle.loads(pickle.dumps(CampaignContext.from_config(config, tmp_path / f"point-{worker.MAX_CONTEXTS + 7}")))
    assert recent.store_root == str(tmp_path / f"point-{worker.MAX_CONTEXTS + 7}")
