from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
REALDATA = REPO.parent / "shared" / "realdata"


@pytest.fixture(scope="session")
def mer_a_path() -> Path:
    return REPO / "sitedata" / "cameras" / "mer_a.toml"


@pytest.fixture(scope="session")
def mer_a(mer_a_path):
    from flight_interface.camera import load_camera

    return load_camera(mer_a_path)


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
def pytest_terminal_summary(terminalreporter):
    """The fuzz suite's size (tests/campaign/test_config_fuzz.py): how many bad inputs it tried, by kind."""
    import sys

    fuzz = sys.modules.get("test_config_fuzz")
    if fuzz is not None and fuzz.TRIED:
        kinds = ", ".join(f"{kind} {count}" for kind, count in sorted(fuzz.TRIED.items()))
        terminalreporter.write_line(f"fuzz: {sum(fuzz.TRIED.values())} bad inputs tried ({kinds}); each must give "
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
