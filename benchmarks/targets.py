"""The performance targets of issues #22 ("Twice as fast per case") and #33 (restated with the exact PSF) as
bench-row columns, and the summary table ``make bench`` prints at the end.

A row that carries a target has the columns ``measured`` (the figure, in ``unit``), ``target``, ``bound``
(``max``: the figure must be at most the target, e.g. a time; ``min``: at least, e.g. a speed-up),
``ratio`` = measured / target and ``meets``. A ``max`` target holds at ratio <= 1, a ``min`` target at
ratio >= 1.
"""
from __future__ import annotations

import math
from collections.abc import Iterable

#: the issues' targets: name -> (value, unit, bound); camera, case, estimator, campaigns and presets restated by
#: issue #33 (measured on an idle 2-core machine: 9.7 / 18.7 ms camera, 89 ms case, 7.5 ms estimator, 51.5 s)
CASE_MS = 60.0                    # one case at the default preset, one thread: 3 images + sensors + reference estimator
CAMERA_MS = 5.0                   # camera chain, one 1024x1024 image, exact PSF, one field for the three periods
CAMERA_MOVING_MS = 9.0            # the same, three different fields (moving image)
CAMERA_RMS_DN = 0.02              # the binned path against the full-resolution stages, expected image, case scenes
PYXEL_SPEEDUP = 50.0              # camera chain (PSF off) against Pyxel's 1024x1024 detector chain, same run
ESTIMATOR_MS = 6.0                # the reference estimator, one estimate
CAMPAIGNS_WALL_S = 35.0           # Gusev + Meridiani (630 cases), embedded 2-worker cluster, cluster start included
WORKER_RSS_MIB = 1024.0           # peak RSS of a campaign worker process
PARALLEL_EFFICIENCY = 0.95        # one-thread median case / median case on 2 workers
REFERENCE_IMAGE_MS = 1000.0       # one image at the reference preset
RMS_DN_VS_REFERENCE = 0.5         # default vs reference preset, expected image
VELOCITY_CHANGE_MPS = 0.05        # default vs reference preset, estimated velocity
FAST_CASE_RATIO = 0.5             # fast preset case time / default preset case time, same run
# issue #34, the campaign store at 10^6 cases (benchmarks/bench_store.py), seconds
STORE_STATUS_S = 10.0             # `campaign status`
STORE_RESUME_SCAN_S = 10.0        # what `campaign submit` reads before it submits a case
STORE_TABLE_S = 5.0               # `campaign table`
STORE_COMPACT_INCREMENTAL_S = 10.0  # compaction after 1 % new cases (the cost of the new cases only)
# issue #34, the runner: scheduler and driver CPU per no-op case, 10^5 cases (benchmarks/bench_orchestration.py)
ORCHESTRATION_MS_PER_CASE = 1.0


def target_columns(measured: float, target: float, unit: str, at_most: bool = True) -> dict:
    """The target columns of a bench row.

    Parameters
    ----------
    measured : float
        The measured figure, in ``unit`` (NaN when it could not be measured: the target is missed).
    target : float
        The target, in ``unit``.
    unit : str
        Unit of both (``ms``, ``s``, ``MiB``, ``DN``, ``m/s``, ``x`` for a ratio).
    at_most : bool
        True: the figure must not exceed the target; False: it must reach it.

    Returns
    -------
    dict
        ``measured``, ``target``, ``unit``, ``bound``, ``ratio`` (measured / target) and ``meets``.
    """
    measured = float(measured)
    ratio = measured / target
    meets = not math.isnan(measured) and (measured <= target if at_most else measured >= target)
    return {"measured": measured, "target": float(target), "unit": unit, "bound": "max" if at_most else "min",
            "ratio": ratio, "meets": bool(meets)}


def summary_lines(rows: Iterable[dict]) -> list[str]:
    """One line per row with a target: name, measured, bound and target, ratio, PASS / MISS; then the count."""
    targeted = [row for row in rows if "target" in row and "measured" in row]
    if not targeted:
        return []
    names = [str(row["name"]) for row in targeted]
    width = max(len(name) for name in names)
    lines = [f"{'target':<{width}}  {'measured':>12}  {'target':>14}  {'ratio':>7}  result",
             "-" * (width + 48)]
    for name, row in zip(names, targeted):
        sign = "<=" if row["bound"] == "max" else ">="
        lines.append(f"{name:<{width}}  {_number(row['measured']):>8} {row['unit']:<3}  "
                     f"{sign} {_number(row['target']):>7} {row['unit']:<3}  {row['ratio']:>7.3f}  "
                     f"{'PASS' if row['meets'] else 'MISS'}")
    passed = sum(bool(row["meets"]) for row in targeted)
    lines.append(f"{passed} of {len(targeted)} targets met")
    return lines


def _number(value: float) -> str:
    return "nan" if math.isnan(value) else f"{value:.4g}"
