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
