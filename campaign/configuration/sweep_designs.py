"""Designed sweeps: the points of ``[sweep] mode = "sobol"`` and ``mode = "morris"``, sampled with SALib from
the axes' ranges.

In these modes every axis is a range ``[low, high]`` (TOML units, as the campaign field: degrees...), two
numbers with ``low < high``; an axis of two integers is an integer axis (its points take integer values, each
value of ``low..high`` with equal probability). The design's size is ``[sweep] samples`` (``N``):

- ``sobol``: Saltelli's scheme on a scrambled Sobol sequence (``SALib.sample.sobol``, first-order and total
  indices, no second order): ``N * (D + 2)`` points for ``D`` axes; ``N`` a power of two;
- ``morris``: ``N`` elementary-effect trajectories on a 4-level grid (``SALib.sample.morris``):
  ``N * (D + 1)`` points (screening: which inputs matter at all).

The design's rows keep their order (the analysis needs it); two rows of one configuration (an integer axis,
a Morris grid) share one point store. The same ``[sweep] design_seed`` gives the same points.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from config_tables.errors import ConfigError

DESIGN_MODES = ("sobol", "morris")
MORRIS_LEVELS = 4


def design_problem(axes: dict[str, Any], label: str) -> dict:
    """SALib's problem of a designed sweep's axes: names, bounds and which axes are integers.

    Parameters
    ----------
    axes : dict
        Axis field -> ``[low, high]``.
    label : str
        The sweep file (for the one-line error).

    Raises
    ------
    ConfigError
        An axis that is not two numbers with ``low < high``.
    """
    names, bounds, integer = [], [], []
    for name, values in axes.items():
        numeric = isinstance(values, list) and len(values) == 2 and all(
            isinstance(value, (int, float)) and not isinstance(value, bool) for value in values)
        if not numeric or not values[0] < values[1]:
            raise ConfigError(f"{label}: axes.{name} = {values!r}: a designed sweep (mode sobol or morris) takes a "
                              "range; allowed: [low, high], two numbers with low < high")
        is_integer = all(isinstance(value, int) for value in values)
        names.append(name)
        # an integer axis is sampled on [low, high + 1) and floored: every integer equally likely
        bounds.append([float(values[0]), float(values[1]) + (1.0 if is_integer else 0.0)])
        integer.append(is_integer)
    return {"num_vars": len(names), "names": names, "bounds": bounds, "integer": integer}


def design_matrix(mode: str, problem: dict, samples: int, seed: int, label: str) -> np.ndarray:
    """The design's rows in SALib's order, shape (rows, axes), before integer axes are floored.

    Raises
    ------
    ConfigError
        ``samples`` not allowed for ``mode`` (Sobol: a power of two, at least 2; Morris: at least 2).
    """
    from SALib.sample import morris as morris_sample
    from SALib.sample import sobol as sobol_sample

    salib_problem = {key: problem[key] for key in ("num_vars", "names", "bounds")}
    if mode == "sobol":
        if samples < 2 or samples & (samples - 1):
            raise ConfigError(f"{label}: sweep.samples = {samples}; allowed: a power of two >= 2 for mode "
                              "\"sobol\" (Saltelli's scheme keeps its balance only then)")
        return sobol_sample.sample(salib_problem, samples, calc_second_order=False, scramble=True, seed=seed)
    if mode == "morris":
        if samples < 2:
            raise ConfigError(f"{label}: sweep.samples = {samples}; allowed: at least 2 trajectories for mode \"morris\"")
        return morris_sample.sample(salib_problem, samples, num_levels=MORRIS_LEVELS, seed=seed)
    raise ConfigError(f"{label}: sweep.mode = {mode!r}; allowed: {', '.join(DESIGN_MODES)}")


def point_values(problem: dict, matrix: np.ndarray) -> list[dict]:
    """Each design row as a point's axis values (field -> value; integer axes floored into ``[low, high]``,
    the others rounded to 12 significant digits so a value prints and hashes stably)."""
    points = []
    for row in matrix:
        values: dict[str, Any] = {}
        for name, value, (low, high), is_integer in zip(problem["names"], row, problem["bounds"], problem["integer"]):
            if is_integer:
                values[name] = int(min(np.floor(value), high - 1.0))
            else:
                values[name] = float(f"{min(max(value, low), high):.12g}")
        points.append(values)
    return points


def design_points(mode: str, axes: dict[str, Any], samples: int, seed: int, label: str) -> list[dict]:
    """The points of a designed sweep, in design order (module docstring)."""
    problem = design_problem(axes, label)
    return point_values(problem, design_matrix(mode, problem, samples, seed, label))
