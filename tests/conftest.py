"""Fixtures and hooks shared by the whole suite.

Layout: a test file sits in the directory that mirrors the (sub)package it tests: ``tests/campaign/run/`` tests
``campaign/run/``, ``tests/simulator/scene/`` tests ``simulator/scene/``, ``tests/simulator/`` the modules at the
top of ``simulator/``. Files that drive a command line end to end across subpackages (bad input, no traceback, the
fuzz suite) sit at their package's level (``tests/campaign/``); tests of the whole tree at the top.

Test directories are not packages (no ``__init__.py``): pytest's default ("prepend") import mode puts each test
file's directory and this one on ``sys.path``, so test file names are unique across the tree, and the helper
modules beside this file (``service_campaigns``, ``fuzz_inputs``, ``planetary_files``, ``synthetic_descent``,
``adversarial_*``, ``plugins/``) are imported by bare name. No test imports another test file.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
REALDATA = REPO.parent / "shared" / "realdata"
#: environment variable naming the file tests/numba_warmup.py writes when the numba cache is warm (set by the
#: controlling pytest process for its xdist processes, which wait for the file before their first test)
NUMBA_WARMUP_DONE = "M2D_TESTS_NUMBA_WARMUP_DONE"
_PACKAGES = ("simulator", "dimes_velocity", "campaign", "estimators", "sitedata", "flight_interface", "file_formats")


def _numba_cache_is_stale() -> bool:
    """Whether the checkout's numba cache needs the warm-up: no cached pass at all (a clean clone), or a module
    of cached (``cache=True``) passes edited after its cache was written."""
    cached_any = False
    for package in _PACKAGES:
        for source in (REPO / package).rglob("*.py"):
            if "cache=True" not in source.read_text(errors="replace"):
                continue
            indexes = list((source.parent / "__pycache__").glob(f"{source.stem}.*.nbi"))
            cached_any = cached_any or bool(indexes)
            if any(index.stat().st_mtime < source.stat().st_mtime for index in indexes):
                return True
    return not cached_any


_WARMUP = pytest.StashKey[subprocess.Popen]()


def pytest_configure(config):
    """In the controlling process of an xdist run (``-n 2``): when the numba cache is cold, start
    tests/numba_warmup.py, which compiles the case code's passes once while the xdist processes start and collect;
    they wait for it before their first test (``_numba_cache_warm``) instead of each compiling the same passes, with
    the workers of their warm clusters, at the same time."""
    if hasattr(config, "workerinput") or not config.getoption("numprocesses", None) or NUMBA_WARMUP_DONE in os.environ:
        return
    if not _numba_cache_is_stale():
        return
    done = Path(tempfile.mkdtemp(prefix="m2d-numba-warmup-")) / "done"
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
    config.stash[_WARMUP] = subprocess.Popen([sys.executable, str(Path(__file__).with_name("numba_warmup.py")), str(done)],
                                             cwd=REPO, env=environment, stdout=subprocess.DEVNULL,
                                             stderr=subprocess.DEVNULL)
    os.environ[NUMBA_WARMUP_DONE] = str(done)          # inherited by the xdist processes started after this


def pytest_unconfigure(config):
    process = config.stash.get(_WARMUP, None)
    if process is not None:
        if process.poll() is None:
            process.kill()
        process.wait()
        done = Path(os.environ.pop(NUMBA_WARMUP_DONE))
        done.unlink(missing_ok=True)
        done.parent.rmdir()


@pytest.fixture(scope="session", autouse=True)
def _numba_cache_warm() -> None:
    """In an xdist process of a run whose controller started the numba warm-up (``pytest_configure``): wait until
    it has written the cache (at most 10 minutes; it writes its file even when it fails)."""
    done = os.environ.get(NUMBA_WARMUP_DONE)
    deadline = time.monotonic() + 600
    while done and not os.path.exists(done) and time.monotonic() < deadline:
        time.sleep(0.2)


@pytest.fixture(scope="session")
def mer_a_path() -> Path:
    return REPO / "sitedata" / "cameras" / "mer_a.toml"


@pytest.fixture(scope="session")
def mer_a(mer_a_path):
    from flight_interface.camera import load_camera

    return load_camera(mer_a_path)


@pytest.fixture(scope="session")
def warm_scheduler() -> Iterator[str]:
    """The address (``tcp://127.0.0.1:port``) of one embedded campaign cluster that this test process starts at
    its first use and keeps for the session: ``campaign.run.cluster.start_cluster`` with two single-threaded
    workers, the same LocalCluster ``campaign submit`` embeds. For tests where the cluster is incidental to
    what they check (store files, identity, locks, sweeps, gates, reports): they pass it as ``--scheduler`` and
    pay no cluster start-up and no worker imports of the case code per command (about 5-10 s each on the
    2-core machine). Tests of the cluster itself (killed workers, interrupts, worker counts, plug-in set-up on
    fresh workers, SLURM) start their own."""
    from service_campaigns import embedded_scheduler

    yield from embedded_scheduler(2)


@pytest.fixture(scope="session")
def site_strips(tmp_path_factory):
    """The shipped classes of both sites (preset + seed from the site files), full size:
    ``{class: (site name, ellipse fraction, Terrain)}``, built once per session in a fresh cache."""
    from sitedata.sites import class_terrain_params, load_site
    from sitedata.terrain import synthetic_terrain

    cache = tmp_path_factory.mktemp("terrain_cache")
    strips = {}
    for site_file in (REPO / "sitedata" / "gusev.toml", REPO / "sitedata" / "meridiani.toml"):
        site = load_site(site_file)
        for site_class in site.classes:
            params = class_terrain_params(site_class.terrain)
            terrain = synthetic_terrain.synthetic_terrain(params, site_class.terrain.seed, cache_dir=cache)
            strips[site_class.name] = (site.name, site_class.ellipse_fraction, terrain)
    return strips
def _fuzz_counts() -> dict[str, int]:
    """The bad inputs the fuzz suite (tests/campaign/test_config_fuzz.py) tried in this process, by kind."""
    import sys

    fuzz = sys.modules.get("test_config_fuzz")
    return dict(fuzz.TRIED) if fuzz is not None else {}


_FUZZ_TRIED_BY_WORKERS: dict[str, int] = {}


def pytest_sessionfinish(session):
    """In a pytest-xdist worker: hand this process's fuzz counts to the controlling process."""
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:
        workeroutput["fuzz_tried"] = _fuzz_counts()


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    """In the controlling process: add up the fuzz counts each xdist worker ran (xdist's hook)."""
    for kind, count in getattr(node, "workeroutput", {}).get("fuzz_tried", {}).items():
        _FUZZ_TRIED_BY_WORKERS[kind] = _FUZZ_TRIED_BY_WORKERS.get(kind, 0) + count


def pytest_terminal_summary(terminalreporter):
    """The fuzz suite's size: how many bad inputs it tried, by kind, summed over the test processes."""
    tried = dict(_FUZZ_TRIED_BY_WORKERS)
    for kind, count in _fuzz_counts().items():
        tried[kind] = tried.get(kind, 0) + count
    if tried:
        kinds = ", ".join(f"{kind} {count}" for kind, count in sorted(tried.items()))
        terminalreporter.write_line(f"fuzz: {sum(tried.values())} bad inputs tried ({kinds}); each must give "
                                    "exit 2, one stderr line, nothing written")


def pytest_collection_modifyitems(items):
    """Files with the most cluster and slow tests first (longest first): the two test processes
    (``-n 2 --dist loadfile``) take files in this order, so the short unit-test files fill the end instead of
    one process running a long cluster file alone while the other waits."""
    weight: dict[str, int] = {}
    for item in items:
        weight[str(item.path)] = (weight.get(str(item.path), 0) + 4 * bool(item.get_closest_marker("cluster"))
                                  + bool(item.get_closest_marker("slow")))
    items.sort(key=lambda item: -weight[str(item.path)])     # stable: files of equal weight keep their order
