"""The planner's scrambled Halton sequence is scipy's, bit for bit, without importing scipy.stats."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.stats import qmc

from campaign.plan.halton import scrambled_halton


def _scipy(count: int, dimensions: int, seed_sequence: np.random.SeedSequence) -> np.ndarray:
    return qmc.Halton(d=dimensions, scramble=True, rng=np.random.default_rng(seed_sequence)).random(count)


@pytest.mark.parametrize("dimensions", [1, 3, 5])
def test_the_points_are_scipy_s_engine_s_bit_for_bit(dimensions):
    compared = 0
    for seed in range(40):
        for spawn_key in [(), (0,), (3, 7)]:
            for count in (1, 2, 7, 100, 1000):
                ours = scrambled_halton(count, dimensions, np.random.SeedSequence(seed * 7919 + 13, spawn_key=spawn_key))
                theirs = _scipy(count, dimensions, np.random.SeedSequence(seed * 7919 + 13, spawn_key=spawn_key))
                assert ours.shape == theirs.shape == (count, dimensions)
                assert ours.tobytes() == theirs.tobytes(), (seed, spawn_key, count)
                compared += 1
    assert compared == 600


def test_a_long_sequence_is_scipy_s_and_every_prefix_is_its_own_start():
    ours = scrambled_halton(200_000, 3, np.random.SeedSequence(1))
    assert ours.tobytes() == _scipy(200_000, 3, np.random.SeedSequence(1)).tobytes()
    assert np.array_equal(scrambled_halton(1234, 3, np.random.SeedSequence(1)), ours[:1234])
    assert ours.min() >= 0.0 and ours.max() < 1.0


def test_the_caller_s_seed_sequence_spawns_one_child_as_with_scipy():
    ours, theirs = np.random.SeedSequence(5), np.random.SeedSequence(5)
    scrambled_halton(10, 3, ours)
    _scipy(10, 3, theirs)
    assert ours.n_children_spawned == theirs.n_children_spawned == 1


def test_no_points_and_bad_dimensions():
    assert scrambled_halton(0, 3, np.random.SeedSequence(1)).shape == (0, 3)
    for dimensions, count in ((0, 5), (11, 5), (3, -1)):
        with pytest.raises(ValueError, match="scrambled Halton"):
            scrambled_halton(count, dimensions, np.random.SeedSequence(1))


def test_planning_imports_no_scipy_stats():
    code = ("import sys; from pathlib import Path; from campaign.configuration.campaign_file import load_campaign_config; "
            "from campaign.run.planning import plan_campaign; "
            "plan_campaign(load_campaign_config(Path('sitedata/gusev.toml'), cases_scale=0.1)); "
            "print('scipy.stats' in sys.modules)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                            cwd=__file__.rsplit("/tests/", 1)[0])
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "False"
