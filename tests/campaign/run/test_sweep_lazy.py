"""A sweep at many points starts computing at once, with progress, and keeps results/resume semantics.

Real parts: `campaign sweep` in a subprocess (its own LocalCluster of worker processes), real point stores;
SIGINT as a user's Ctrl-C. The large sweep is 2000 grid points of one case each: point stores are prepared
as the sweep reaches them (a batch of at most ``BATCH_POINTS``), so the first batch is submitted within
seconds and, when the first case file appears, only the first batches' stores exist. The resumed sweep runs
in batches of two points: every planned case ends up stored exactly once and the cases kept from the
interrupted run are not computed again.
"""
from __future__ import annotations

import re
import time
from pathlib import Path

import pandas as pd
import pytest

# the large sweep's grid and its run until the first case file are the benchmark sweep/2000_points_first_batch's
from benchmarks.bench_sweep_start import WIDE_AXES
from benchmarks.bench_sweep_start import start_and_interrupt as _interrupt_at_first_case
from benchmarks.bench_sweep_start import sweep_file as _sweep_file
from campaign.cli import main


def _case_files(out: Path) -> dict:
    return {p.relative_to(out): (p.stat().st_ino, p.stat().st_mtime_ns) for p in out.glob("points/*/cases/*/batch-*.parquet")}


@pytest.mark.cluster
@pytest.mark.slow
def test_a_sweep_of_2000_points_starts_computing_at_its_first_batch_with_progress(tmp_path):
    """Behaviour here; how soon (<= 10 s to the first batch) is the benchmark sweep/2000_points_first_batch."""
    from campaign.run.sweep import BATCH_POINTS, FIRST_BATCH_POINTS

    lines, first_case, stores, code = _interrupt_at_first_case(_sweep_file(tmp_path / "wide.toml", WIDE_AXES),
                                                               tmp_path / "out")
    text = "\n".join(f"{at:6.1f} s  {line}" for at, line in lines)
    assert lines and lines[0][1].startswith("sweep: 2000 points of 1 cases"), text
    first_batch = rf"sweep: points p000-p{FIRST_BATCH_POINTS - 1:03d} \({FIRST_BATCH_POINTS} of 2000\): 0 cases done"
    batch = next((at for at, line in lines if re.match(first_batch, line)), None)
    assert batch is not None, text
    assert first_case is not None and batch < first_case, text      # the first batch is announced, then computed
    assert 1 <= stores <= FIRST_BATCH_POINTS + BATCH_POINTS, f"{stores} point stores prepared before the first case"
    assert code == 130 and "Traceback" not in text, text
    print(f"2000 points: first progress line {lines[0][0]:.1f} s, first batch submitted {batch:.1f} s, "
          f"first case file {first_case:.1f} s, {stores} point stores then")


@pytest.fixture(scope="module")
def scheduler(warm_scheduler) -> str:
    """The test process's warm cluster (``warm_scheduler``, tests/conftest.py): its start-up is not tested here."""
    return warm_scheduler


@pytest.mark.cluster
@pytest.mark.slow
def test_an_interrupted_sweep_resumes_in_batches_without_losing_or_repeating_a_case(tmp_path, scheduler, monkeypatch,
                                                                                     capsys):
    """Slow by design (35-85 s on the shared 2-core machine, 2026-11-27): a 6-point sweep is interrupted at its
    first case file in a subprocess with its own embedded cluster, then resumed in this process on the warm
    cluster (``scheduler``); the interruption of a process with its own cluster is the behaviour under test, so
    that cluster cannot be shared away."""
    import campaign.run.sweep as sweep_module

    sweep = _sweep_file(tmp_path / "small.toml", {"scene.camera_effects.dark_current_scale": [1.0, 2.0, 3.0],
                                                  "sensors.attitude_random_sigma_deg": [0.05, 0.1]})
    out = tmp_path / "out"
    _, first_case, _, code = _interrupt_at_first_case(sweep, out)
    assert first_case is not None and code == 130
    kept = _case_files(out)
    assert len(kept) >= 1
    monkeypatch.setattr(sweep_module, "BATCH_POINTS", 2)       # three batches of two points
    code = main(["sweep", str(sweep), "--output", str(out), "--scheduler", scheduler, "--no-progress"])
    stdout = capsys.readouterr().out
    assert code == 0, stdout
    after = _case_files(out)
    assert {path: after[path] for path in kept} == kept, "a case kept from the interrupted run was computed again"
    assert len(after) == 6 and len({path.parts[1] for path in after}) == 6          # one case in each point store
    assert f"{6 - len(kept)} cases done" in stdout or len(kept) == 6, stdout
    results = pd.read_parquet(out / "results.parquet")
    assert sorted(results["point_id"]) == [f"p{i:03d}" for i in range(6)]               # one row per point
    assert not results.duplicated(["point_id", "case_id"]).any()
    assert results["config_hash"].nunique() == 6


def test_a_bad_value_anywhere_in_a_10000_point_grid_is_refused_before_anything_is_written(tmp_path, capsys):
    rates = [0.01 * (i + 1) for i in range(100)]
    rates[73] = -0.5                                          # one bad value, met first at point p073
    sweep = _sweep_file(tmp_path / "grid.toml", {"scene.camera_effects.dark_current_scale": [1.0 + i for i in range(100)],
                                                 "sensors.attitude_random_sigma_deg": rates})
    out = tmp_path / "out"
    start = time.perf_counter()
    code = main(["sweep", str(sweep), "--output", str(out), "--no-progress"])
    elapsed = time.perf_counter() - start
    stderr = capsys.readouterr().err.strip()
    assert code == 2 and len(stderr.splitlines()) == 1, stderr
    assert "sensors.attitude_random_sigma_deg" in stderr and "-0.5" in stderr and str(sweep) in stderr, stderr
    assert not out.exists() and elapsed < 30.0


def test_the_points_validated_first_hold_every_axis_value():
    from campaign.configuration.sweep_file import EAGER_POINTS, eager_indices

    grid = [{"a": a, "b": b, "c": c} for a in range(20) for b in range(30) for c in (True, False)]   # 1200 points
    chosen = eager_indices(grid)
    assert chosen[0] == 0 and chosen == sorted(set(chosen)) and len(chosen) <= EAGER_POINTS
    for name, values in (("a", range(20)), ("b", range(30)), ("c", (True, False))):
        assert {grid[i][name] for i in chosen} == set(values)
    small = grid[:EAGER_POINTS]
    assert eager_indices(small) == list(range(EAGER_POINTS))                         # a small sweep: every point
    listed = [{"a": i, "b": -i} for i in range(1000)]                              # more values than the limit
    assert eager_indices(listed) == list(range(EAGER_POINTS))
