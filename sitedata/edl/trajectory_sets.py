"""Stored EDL trajectory sets: regenerate, verify bit for bit, and print their statistics.

Usage (from the repository root)::

    python -m sitedata.edl.trajectory_sets generate [SITE ...]   # rewrite sitedata/trajectories/<site>.parquet
    python -m sitedata.edl.trajectory_sets verify [SITE ...]     # regenerate in memory, compare with the files
    python -m sitedata.edl.trajectory_sets stats [SITE|FILE ...] # statistics + check against the paper

SITE is the name of a parameter file ``sitedata/trajectories/edl_<SITE>.toml`` (default: every one) or
the path of any parameter file (``.toml``, fields: :class:`sitedata.edl.parameters.EdlParameters`).
``stats`` also accepts any trajectory file (``.parquet`` / ``.csv``). Exit status 1 when a check or a
verification fails; 2 with one line on stderr (naming the file and field) for bad input, nothing written.
The paper's ranges (section 5) checked by ``stats``: images at 2000 / 1725 /
~1450 m, 3.75 s between images 2 and 3, vertical speed ~72 m/s, off-nadir < 30 deg, roll < 45 deg,
angular rate < 60 deg/s, horizontal speed < 30 m/s, heat shield 140-200 m axial and 50-75 m lateral
from the lander at the images; with both sites, Gusev windier with larger attitude excursions.
"""
from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from config_tables.command_line import USAGE_ERROR, OneLineParser
from config_tables.errors import ConfigError
from sitedata import SITEDATA_DIR
from sitedata.edl.generator import generate_profiles, load_edl_parameters, profile_statistics
from sitedata.edl.trajectory_io import compact_frame, profiles_to_frame, read_profiles, write_profiles

TRAJECTORY_DIR = SITEDATA_DIR / "trajectories"

# (statistic columns, low, high) - the paper's representative values; None = unbounded
PAPER_RANGES: dict[str, tuple[list[str], float | None, float | None]] = {
    "altitude at image 1 (m)": (["altitude_image1_m"], 1999.0, 2001.0),
    "altitude at image 2 (m)": (["altitude_image2_m"], 1724.0, 1726.0),
    "altitude at image 3 (m)": (["altitude_image3_m"], 1400.0, 1500.0),
    "image 2 to 3 (s)": (["image2_to_3_s"], 3.75 - 1e-9, 3.75 + 1e-9),
    "vertical speed at images (m/s)": ([f"vertical_speed_image{k}_mps" for k in (1, 2, 3)], 62.0, 82.0),
    "off-nadir max (deg)": (["off_nadir_max_deg"], 0.0, 30.0),
    "roll max (deg)": (["roll_max_deg"], 0.0, 45.0),
    "angular rate max (deg/s)": (["angular_rate_max_dps"], 0.0, 60.0),
    "horizontal speed max (m/s)": (["horizontal_speed_max_mps"], 0.0, 30.0),
    "steady wind at images (m/s)": ([f"wind_speed_image{k}_mps" for k in (1, 2, 3)], None, None),
    "heat shield axial (m)": ([f"heat_shield_axial_image{k}_m" for k in (1, 2, 3)], 140.0, 200.0),
    "heat shield lateral (m)": ([f"heat_shield_lateral_image{k}_m" for k in (1, 2, 3)], 50.0, 75.0),
}
VERTICAL_SPEED_MEAN_RANGE_MPS = (70.0, 74.0)


def parameter_files(sites: list[str]) -> list[Path]:
    if not sites:
        return sorted(TRAJECTORY_DIR.glob("edl_*.toml"))
    files = []
    for site in sites:
        if site.endswith(".toml"):
            files.append(Path(site))          # a parameter file given by path (validated when loaded)
            continue
        path = TRAJECTORY_DIR / f"edl_{site}.toml"
        if not path.is_file():
            known = ", ".join(p.stem[4:] for p in sorted(TRAJECTORY_DIR.glob("edl_*.toml")))
            raise ConfigError(f"{path}: no such trajectory set parameter file; allowed sites: {known}")
        files.append(path)
    return files


def set_statistics(path: str | Path) -> pd.DataFrame:
    """One row of :func:`~sitedata.edl.generator.profile_statistics` per profile of a trajectory file."""
    return pd.DataFrame([profile_statistics(p) for p in read_profiles(path)])


def _allowed(low: float | None, high: float | None) -> str:
    """The range [low, high) as printed (None: no bound on that side)."""
    if low is None and high is None:
        return "(reported)"
    if low is None:
        return f"< {high:g}"
    if high is None:
        return f">= {low:g}"
    return f"= {0.5 * (low + high):g}" if high - low < 1e-6 else f"[{low:g}, {high:g})"


def check_set(stats: pd.DataFrame) -> list[tuple[str, float, float, float, str, bool]]:
    """Rows (quantity, min, mean, max, allowed, ok) checking a set's statistics against the paper."""
    rows = []
    for label, (columns, low, high) in PAPER_RANGES.items():
        present = [c for c in columns if c in stats]
        if not present:
            rows.append((label, np.nan, np.nan, np.nan, "column missing", False))
            continue
        values = stats[present].to_numpy().ravel()
        ok = bool((low is None or values.min() >= low) and (high is None or values.max() < high))
        rows.append((label, values.min(), values.mean(), values.max(), _allowed(low, high), ok))
    vertical = stats[[f"vertical_speed_image{k}_mps" for k in (1, 2, 3)]].to_numpy().mean()
    low, high = VERTICAL_SPEED_MEAN_RANGE_MPS
    rows.append(("vertical speed mean (~72 m/s)", vertical, vertical, vertical, f"[{low:g}, {high:g}]",
                 bool(low <= vertical <= high)))
    return rows


def compare_sites(windy: pd.DataFrame, calm: pd.DataFrame) -> list[tuple[str, float, float, bool]]:
    """Gusev (``windy``) must have more wind and larger attitude excursions than Meridiani (``calm``)."""
    rows = []
    for label, column in (("mean steady wind at image 1 (m/s)", "wind_speed_image1_mps"),
                          ("mean off-nadir max (deg)", "off_nadir_max_deg"),
                          ("mean roll max (deg)", "roll_max_deg"),
                          ("mean angular rate max (deg/s)", "angular_rate_max_dps")):
        a, b = float(windy[column].mean()), float(calm[column].mean())
        rows.append((label, a, b, a > b))
    return rows


def _print_checks(name: str, stats: pd.DataFrame) -> bool:
    rows = check_set(stats)
    print(f"\n{name}: {len(stats)} profiles")
    print(f"  {'quantity':34s} {'min':>10s} {'mean':>10s} {'max':>10s}  {'paper':>14s}")
    for label, low, mean, high, allowed, ok in rows:
        print(f"  {label:34s} {low:10.3f} {mean:10.3f} {high:10.3f}  {allowed:>14s}  {'ok' if ok else 'FAIL'}")
    return all(r[-1] for r in rows)


def command_stats(targets: list[str]) -> bool:
    paths = []
    for target in targets or [p.stem[4:] for p in parameter_files([])]:
        candidate = Path(target)
        paths.append(candidate if candidate.suffix in (".parquet", ".csv")
                     else load_edl_parameters(parameter_files([target])[0]).output_path)
    tables = {path.stem: set_statistics(path) for path in paths}      # every file read before printing
    ok = True
    for path in paths:
        ok &= _print_checks(str(path), tables[path.stem])
    if "gusev" in tables and "meridiani" in tables:
        print("\nGusev vs Meridiani (paper: Gusev windier, larger attitude excursions)")
        for label, a, b, good in compare_sites(tables["gusev"], tables["meridiani"]):
            print(f"  {label:34s} {a:10.3f} {b:10.3f}  {'ok' if good else 'FAIL'}")
            ok &= good
    print("\nall checks passed" if ok else "\nSOME CHECKS FAILED")
    return ok


def command_generate(sites: list[str]) -> bool:
    for params in [load_edl_parameters(path) for path in parameter_files(sites)]:   # all valid before writing
        profiles, attempts = generate_profiles(params)
        write_profiles(params.output_path, profiles, compact=True)
        digest = hashlib.sha256(params.output_path.read_bytes()).hexdigest()[:16]
        print(f"{params.output_path}: {len(profiles)} profiles, {sum(a > 0 for a in attempts)} redrawn "
              f"({sum(attempts)} draws outside the envelope), {params.output_path.stat().st_size / 1e6:.2f} MB, "
              f"sha256 {digest}")
    return True


def command_verify(sites: list[str]) -> bool:
    ok = True
    for path in parameter_files(sites):
        params = load_edl_parameters(path)
        profiles, _ = generate_profiles(params)
        expected = compact_frame(profiles_to_frame(profiles))
        if not params.output_path.is_file():
            raise ConfigError(f"{path}: set.output = {params.output_path}: file not found (run generate first)")
        stored = pq.read_table(params.output_path).to_pandas()
        same = list(stored.columns) == list(expected.columns) and len(stored) == len(expected) and all(
            stored[c].dtype == expected[c].dtype and np.array_equal(stored[c].to_numpy().view(np.uint8),
                                                                    expected[c].to_numpy().view(np.uint8))
            for c in expected.columns)
        print(f"{params.output_path}: {'identical to a fresh regeneration (bit for bit)' if same else 'DIFFERS from a fresh regeneration'}")
        ok &= same
    return ok


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python -m sitedata.edl.trajectory_sets", description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=("generate", "verify", "stats"))
    parser.add_argument("targets", nargs="*", help="site names (edl_<site>.toml) or, for stats, trajectory files")
    args = parser.parse_args(argv)
    handler = {"generate": command_generate, "verify": command_verify, "stats": command_stats}[args.command]
    try:
        return 0 if handler(args.targets) else 1
    except ConfigError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return USAGE_ERROR


if __name__ == "__main__":
    sys.exit(main())
