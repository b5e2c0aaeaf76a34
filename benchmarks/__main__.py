"""`make bench`: run every benchmarks/bench_*.py module's run() and print its rows (also as CSV), then one
summary line per target of issue #22 (benchmarks/targets.py): measured, target, ratio, PASS / MISS.

``python -m benchmarks camera estimator`` runs only the named modules."""
from __future__ import annotations

import os

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")     # budgets are per core: one thread everywhere

import csv
import importlib
import pkgutil
import sys
import time
from pathlib import Path

import benchmarks
from benchmarks.targets import summary_lines


def main(argv: list[str] | None = None) -> int:
    import cv2

    cv2.setNumThreads(1)
    selected = set(sys.argv[1:] if argv is None else argv)
    output_dir = Path("bench-results")
    output_dir.mkdir(exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%S")
    all_rows: list[dict] = []
    for module_info in sorted(pkgutil.iter_modules(benchmarks.__path__), key=lambda m: m.name):
        if not module_info.name.startswith("bench_"):
            continue
        short = module_info.name.removeprefix("bench_")
        if selected and short not in selected:
            continue
        module = importlib.import_module(f"benchmarks.{module_info.name}")
        print(f"== {short}")
        for row in module.run():
            row = {"benchmark": short, **row}
            all_rows.append(row)
            print("  " + "  ".join(f"{k}={_fmt(v)}" for k, v in row.items() if k != "benchmark"), flush=True)
    if all_rows:
        fields = list(dict.fromkeys(key for row in all_rows for key in row))
        path = output_dir / f"bench-{stamp}.csv"
        with path.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=fields)
            writer.writeheader()
            writer.writerows(all_rows)
        print(f"written {path}")
    summary = summary_lines(all_rows)
    if summary:
        print("\n== targets (issue #22)")
        print("\n".join(summary))
    return 0


def _fmt(value) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


if __name__ == "__main__":
    sys.exit(main())
