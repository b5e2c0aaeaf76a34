"""The last tasks of a run are cut shorter (campaign.run.dask_runner.balanced_tail): every case is still run
once and in plan order, only the tail is cut, and with cases of equal cost handed to the first free worker
the workers finish within a short task of each other instead of a whole batch apart."""
from __future__ import annotations

import heapq

import pyarrow as pa
import pytest

from campaign.configuration.campaign_file import load_campaign_config
from campaign.run.dask_runner import MAX_CASES_PER_TASK, TAIL_MIN_CASES, CaseBatch, balanced_tail
from campaign.run.worker import CampaignContext
from campaign.store.campaign_store import CampaignStore
from service_campaigns import campaign_file


def _batches(tmp_path, name: str, first_id: int, cases: int, size: int, execution: str = "") -> list[CaseBatch]:
    """Plan-like rows cut into tasks of ``size`` cases, as batch_cases cuts them."""
    config = load_campaign_config(campaign_file(tmp_path / name, execution=execution))
    context = CampaignContext.from_config(config, tmp_path / name / "store")
    store = CampaignStore(tmp_path / name / "store")
    rows = [{"case_id": first_id + index, "class_name": "gcp"} for index in range(cases)]
    return [CaseBatch(context, store, pa.Table.from_pylist(rows[start:start + size]), f"cases-{name}-{start}")
            for start in range(0, cases, size)]


def _finish_times(task_sizes: list[int], workers: int) -> list[float]:
    """When each worker finishes, tasks of unit-cost cases handed in order to the first free worker."""
    free = [(0.0, worker) for worker in range(workers)]
    finished = [0.0] * workers
    for size in task_sizes:
        start, worker = heapq.heappop(free)
        finished[worker] = start + size
        heapq.heappush(free, (finished[worker], worker))
    return finished


def test_every_case_once_in_plan_order_and_only_the_tail_cut(tmp_path):
    size = 16           # 40 batches of the two campaigns (the automatic size is larger): many to keep, a tail to cut
    batches = _batches(tmp_path, "gusev", 0, 376, size) + _batches(tmp_path, "meridiani", 5_000_000, 254, size)
    cut = balanced_tail(batches, workers=2)
    ids = [case_id for batch in cut for case_id in batch.case_ids]
    assert ids == [case_id for batch in batches for case_id in batch.case_ids]
    assert len({batch.key for batch in cut}) == len(cut)
    # the batches that start with more than 2 x 2 workers x 16 cases left are kept as they were (36 of 40) ...
    left = [630 - sum(len(batch.rows) for batch in batches[:index]) for index in range(len(batches))]
    kept = sum(1 for count in left if count > 4 * size)
    assert kept == 36 and cut[:kept] == batches[:kept]
    # ... the rest is cut into tasks that shrink towards the end of the run: a few more tasks, not one per case
    tail = [len(batch.rows) for batch in cut[kept:]]
    assert tail == sorted(tail, reverse=True) and tail[-1] <= TAIL_MIN_CASES
    assert len(cut) <= len(batches) + 12
    # a task cut from a batch stays with its campaign and store
    for batch in cut:
        assert {case_id // 5_000_000 for case_id in batch.case_ids} == {0 if batch.context.config is
                                                                        batches[0].context.config else 1}


@pytest.mark.parametrize("workers", [2, 3, 8])
def test_workers_finish_within_a_short_task(tmp_path, workers):
    size = MAX_CASES_PER_TASK["compute"]
    batches = _batches(tmp_path, "gusev", 0, 630, size)
    before = _finish_times([len(batch.rows) for batch in batches], workers)
    after = _finish_times([len(batch.rows) for batch in balanced_tail(batches, workers)], workers)
    assert sum(after) == sum(before) == 630
    assert max(after) - min(after) <= TAIL_MIN_CASES
    assert max(after) <= max(before)
    assert max(after) <= 630 / workers + TAIL_MIN_CASES


def test_a_size_set_in_the_execution_table_is_kept(tmp_path):
    batches = _batches(tmp_path, "gusev", 0, 100, 16, execution="cases_per_task = 16")
    assert balanced_tail(batches, workers=2) == batches
