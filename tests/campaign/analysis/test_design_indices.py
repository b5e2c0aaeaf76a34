"""Designed sweeps' points and indices against functions with known indices."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from campaign.analysis.design_indices import design_indices, format_design_indices
from campaign.configuration.sweep_designs import design_matrix, design_points, design_problem
from config_tables.errors import ConfigError

PI = math.pi


def ishigami(values: np.ndarray, a: float = 7.0, b: float = 0.1) -> np.ndarray:
    """Ishigami & Homma (1990): sin x1 + a sin^2 x2 + b x3^4 sin x1 on [-pi, pi]^3."""
    return np.sin(values[:, 0]) + a * np.sin(values[:, 1]) ** 2 + b * values[:, 2] ** 4 * np.sin(values[:, 0])


def ishigami_indices(a: float = 7.0, b: float = 0.1) -> tuple[list[float], list[float]]:
    """Closed-form first-order and total Sobol indices of :func:`ishigami` (Sobol' & Levitan 1999)."""
    v1 = 0.5 * (1 + b * PI**4 / 5) ** 2
    v2 = a**2 / 8
    v13 = b**2 * PI**8 * (1 / 18 - 1 / 50)
    total = v1 + v2 + v13
    return [v1 / total, v2 / total, 0.0], [(v1 + v13) / total, v2 / total, v13 / total]


def test_sobol_indices_of_ishigami():
    axes = {"x1": [-PI, PI], "x2": [-PI, PI], "x3": [-PI, PI]}
    problem = design_problem(axes, "t.toml")
    values = np.array([list(point.values()) for point in design_points("sobol", axes, 2048, 0, "t.toml")])
    assert values.shape == (2048 * 5, 3)
    outcomes = pd.DataFrame({("dimes", "pct_valid"): ishigami(values)})
    table, notes = design_indices("sobol", problem, values, outcomes)
    assert not notes
    first, total = ishigami_indices()
    for position, name in enumerate(["x1", "x2", "x3"]):
        rows = table[table["input"] == name].set_index("index")
        assert rows.loc["S1", "value"] == pytest.approx(first[position], abs=0.05)
        assert rows.loc["ST", "value"] == pytest.approx(total[position], abs=0.05)
        # the analytic value inside (or within 0.02 of) the printed interval
        assert rows.loc["ST", "low"] - 0.02 <= total[position] <= rows.loc["ST", "high"] + 0.02
    assert "S1" in format_design_indices(table, notes)


def test_morris_screens_out_an_inert_input():
    """Y = 3 a + b^2 with c inert: mu* of c is 0, of a 3 x the range (effects measured on the unit scale of
    SALib's grid: delta = 2/3 of the range)."""
    axes = {"a": [0.0, 1.0], "b": [0.0, 1.0], "c": [0.0, 1.0]}
    problem = design_problem(axes, "t.toml")
    points = design_points("morris", axes, 20, 1, "t.toml")
    values = np.array([list(point.values()) for point in points])
    outcomes = pd.DataFrame({("dimes", "error"): 3 * values[:, 0] + values[:, 1] ** 2})
    table, _ = design_indices("morris", problem, values, outcomes)
    mu_star = table[table["index"] == "mu_star"].set_index("input")["value"]
    assert mu_star["c"] == pytest.approx(0.0, abs=1e-9)
    assert mu_star["a"] == pytest.approx(3.0, rel=1e-6)
    assert 0.0 < mu_star["b"] < mu_star["a"]


def test_integer_axis_takes_every_value_and_stays_in_range():
    points = design_points("sobol", {"n": [1, 4], "x": [0.5, 2.0]}, 64, 3, "t.toml")
    integers = {point["n"] for point in points}
    assert integers == {1, 2, 3, 4} and all(isinstance(point["n"], int) for point in points)
    assert all(0.5 <= point["x"] <= 2.0 for point in points)


def test_same_seed_same_points_and_bad_ranges_refused():
    axes = {"x": [0.0, 1.0], "y": [2.0, 3.0]}
    assert design_points("sobol", axes, 8, 5, "t.toml") == design_points("sobol", axes, 8, 5, "t.toml")
    with pytest.raises(ConfigError, match=r"t.toml: axes.x = \[1.0, 0.0\].*allowed: \[low, high\]"):
        design_problem({"x": [1.0, 0.0]}, "t.toml")
    with pytest.raises(ConfigError, match="allowed: a power of two"):
        design_matrix("sobol", design_problem(axes, "t.toml"), 6, 0, "t.toml")


def test_undefined_or_constant_outcome_is_a_note():
    axes = {"x": [0.0, 1.0], "y": [0.0, 1.0]}
    problem = design_problem(axes, "t.toml")
    values = np.array([list(point.values()) for point in design_points("sobol", axes, 8, 0, "t.toml")])
    outcomes = pd.DataFrame({("dimes", "false_valid"): np.zeros(len(values)),
                             ("dimes", "error"): np.where(values[:, 0] > 0.9, np.nan, values[:, 1])})
    table, notes = design_indices("sobol", problem, values, outcomes)
    assert table.empty and len(notes) == 2
