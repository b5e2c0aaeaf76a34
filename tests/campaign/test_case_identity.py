"""Case identity is (class, index within class): a quick look is a prefix of the full campaign, and a later,
larger run in the same store computes only the cases it adds; the configuration hash is of content.

Real `campaign submit` processes, a real LocalCluster and real Parquet stores."""
from __future__ import annotations

import pandas as pd
import pyarrow.parquet as pq
import pytest

from service_campaigns import campaign_file, run_campaign

pytestmark = [pytest.mark.cluster, pytest.mark.slow]


def _results(store) -> pd.DataFrame:
    return pq.read_table(store / "results.parquet").to_pandas()


def test_a_larger_run_reuses_the_quick_look_and_equals_a_fresh_run(tmp_path):
    quick = campaign_file(tmp_path / "quick", cases={"gcp": 2, "gdcp": 1, "gkep": 0})
    full = campaign_file(tmp_path / "full", cases={"gcp": 3, "gdcp": 2, "gkep": 0})
    store, fresh_store = tmp_path / "store", tmp_path / "fresh"

    first = run_campaign("submit", quick, "--output", store, "--workers", "1", "--no-progress")
    assert first.returncode == 0, first.stderr
    before = {path.name: path.read_bytes() for path in (store / "cases").glob("case-*")}
    assert len(before) == 3

    larger = run_campaign("submit", full, "--output", store, "--workers", "1", "--no-progress")
    assert larger.returncode == 0, larger.stderr
    assert "(2 done, 0 failed this run)" in larger.stdout     # only the two added cases were computed
    after = {path.name: path.read_bytes() for path in (store / "cases").glob("case-*")}
    assert all(after[name] == data for name, data in before.items())   # the quick look's files untouched

    fresh = run_campaign("submit", full, "--output", fresh_store, "--workers", "2", "--no-progress")
    assert fresh.returncode == 0, fresh.stderr
    reused, computed = _results(store), _results(fresh_store)
    assert sorted(reused["case_id"]) == [0, 1, 2, 1_000_000, 1_000_001]   # (class index, index in class)
    pd.testing.assert_frame_equal(reused, computed, check_exact=True)
