"""How fast the read-only commands answer on a finished Gusev store: ``cli/status``, ``cli/verify``,
``cli/table``, ``cli/schema``, ``cli/help``.

Each command runs as a user runs it, ``campaign <command>`` in its own Python process (start-up and imports
included), :data:`REPEATS` times; the row gives the median wall time (target <= :data:`READ_ONLY_TARGET_S`
each: a read-only command imports only what it reads) and the median CPU time of the process (user +
system, from ``os.wait4``: on a busy machine the wall time also shows the wait for a core, the CPU time
does not).

The store: the full Gusev campaign (``sitedata/gusev.toml``, 376 cases), computed here into a temporary
directory (``campaign submit``, a few minutes on 2 cores), or a copy of an existing finished one named by
the environment variable ``MOC2DIMES_BENCH_GUSEV_STORE`` (copied: ``table`` writes table.md and table.csv
into the store).
"""
from __future__ import annotations

import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.targets import target_columns
from campaign.store.campaign_store import CampaignStore

REPO = Path(__file__).resolve().parents[1]
STORE_VARIABLE = "MOC2DIMES_BENCH_GUSEV_STORE"
READ_ONLY_TARGET_S = 1.0
REPEATS = 5
COMMANDS = {"status": ["status", "{store}"], "verify": ["verify", "{store}"], "table": ["table", "{store}"],
            "schema": ["schema"], "help": ["--help"]}


def _command(arguments: list[str]) -> list[str]:
    """The ``campaign`` entry point with ``arguments`` (the checkout's, whatever is installed)."""
    return [sys.executable, "-c", "import sys; from campaign.cli import main; sys.exit(main())", *arguments]


def gusev_store(root: Path) -> Path:
    """A finished full Gusev store under ``root``: a copy of :data:`STORE_VARIABLE`'s, or computed here."""
    store = root / "gusev"
    given = os.environ.get(STORE_VARIABLE)
    if given:
        shutil.copytree(given, store)
        return store
    subprocess.run(_command(["submit", str(REPO / "sitedata" / "gusev.toml"), "--output", str(store),
                             "--no-progress"]),
                   check=True, stdout=subprocess.DEVNULL, env={**os.environ, "PYTHONPATH": str(REPO)})
    return store


def timed(arguments: list[str]) -> tuple[float, float]:
    """(wall s, CPU s of the process) of one ``campaign`` run; RuntimeError when it does not exit 0."""
    start = time.perf_counter()
    process = subprocess.Popen(_command(arguments), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                               env={**os.environ, "PYTHONPATH": str(REPO)})
    _, status, usage = os.wait4(process.pid, 0)
    wall_s = time.perf_counter() - start
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise RuntimeError(f"campaign {' '.join(arguments)} exited {process.returncode}: "
                           f"{process.stderr.read().decode() if process.stderr else ''}")
    return wall_s, usage.ru_utime + usage.ru_stime


def run() -> list[dict]:
    root = Path(tempfile.mkdtemp(prefix="bench-cli-"))
    try:
        store = gusev_store(root)
        cases = CampaignStore(store).status().done
        rows = []
        for name, template in COMMANDS.items():
            arguments = [part.format(store=store) for part in template]
            timed(arguments)                                    # warm: the files in the page cache
            runs = [timed(arguments) for _ in range(REPEATS)]
            wall_s = statistics.median(wall for wall, _ in runs)
            rows.append({"name": f"cli/{name}", "cases": cases, "repeats": REPEATS,
                         "cpu_s_median": statistics.median(cpu for _, cpu in runs), "load_average": os.getloadavg()[0],
                         **target_columns(wall_s, READ_ONLY_TARGET_S, "s")})
        return rows
    finally:
        shutil.rmtree(root, ignore_errors=True)
