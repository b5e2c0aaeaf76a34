"""Case identity is (class, index within class): a quick look is a prefix of the full campaign, and a later,
larger run in the same store computes only the cases it adds; the configuration hash is of content.

Real `campaign submit` commands (``campaign.cli.main`` in this process: the exit code, stdout and files a
`campaign` process gives, without paying the interpreter start, imports and code digest once per run), a
real LocalCluster (the test process's warm one, ``warm_scheduler`` in tests/conftest.py: the cluster is incidental
here) and real Parquet stores."""
from __future__ import annotations

import pandas as pd
import pytest

from campaign.cli import main
from campaign.store.campaign_store import CampaignStore
from service_campaigns import campaign_file

pytestmark = [pytest.mark.cluster, pytest.mark.slow]


def _results(store) -> pd.DataFrame:
    return CampaignStore(store).results()


def _submit(capsys, *args) -> str:
    """``campaign submit ARGS --no-progress`` run to exit code 0; returns its stdout."""
    capsys.readouterr()
    code = main(["submit", *map(str, args), "--no-progress"])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    return printed.out


def test_a_larger_run_reuses_the_quick_look_and_equals_a_fresh_run(tmp_path, capsys, warm_scheduler):
    quick = campaign_file(tmp_path / "quick", cases={"gcp": 2, "gdcp": 1, "gkep": 0})
    full = campaign_file(tmp_path / "full", cases={"gcp": 3, "gdcp": 2, "gkep": 0})
    store, fresh_store = tmp_path / "store", tmp_path / "fresh"

    _submit(capsys, quick, "--output", store, "--scheduler", warm_scheduler)
    before = {path.name: path.read_bytes() for path in (store / "cases").rglob("batch-*")}
    assert len(before) == 3

    larger = _submit(capsys, full, "--output", store, "--scheduler", warm_scheduler)
    assert "(2 done, 0 failed this run)" in larger     # only the two added cases were computed
    after = {path.name: path.read_bytes() for path in (store / "cases").rglob("batch-*")}
    assert all(after[name] == data for name, data in before.items())   # the quick look's files untouched

    _submit(capsys, full, "--output", fresh_store, "--scheduler", warm_scheduler)
    reused, computed = _results(store), _results(fresh_store)
    assert sorted(reused["case_id"]) == [0, 1, 2, 1_000_000, 1_000_001]   # (class index, index in class)
    pd.testing.assert_frame_equal(reused, computed, check_exact=True)
