"""The estimator never reads truth: the camera every plug-in receives (in-process python, isolated python,
command) has no ``radiometry.prnu_seed``, the seed of the simulator's true PRNU pattern, while the design
numbers (f-number, band, ``prnu_sigma``) arrive unchanged. The probes look for the field's name and its
value (20040104 in mer_a.toml) in everything they are given: the pickled camera, the ``{camera}`` file."""
from __future__ import annotations

import os
import pickle
import sys
from pathlib import Path

import numpy as np
import pytest
from synthetic_descent import constant_velocity_descent, random_ground

from config_tables.errors import ConfigError
from config_tables.toml_file import load_toml
from estimators.camera_view import TRUTH_FIELDS, load_design_camera
from estimators.contract import EstimatorInputs
from estimators.entries import EstimatorSpec
from estimators.plugins import build_estimator, run_estimator
from flight_interface.camera import load_camera

PROBE = '''
import pickle
SEEN = []

def probe(inputs):
    """Invalid, with the reason saying whether the seed's name or value is in what it was given."""
    SEEN.append(inputs.camera)
    data = pickle.dumps(inputs.camera)
    seed = int(inputs.parameters["seed"])
    leaked = b"prnu_seed" in data or hasattr(inputs.camera.radiometry, "prnu_seed") or str(seed) in repr(inputs.camera)
    return {"velocity_east_mps": None, "velocity_north_mps": None, "valid": False,
            "reason": "truth_leaked" if leaked else "design_only"}
'''


@pytest.fixture(scope="module")
def seed(mer_a_path) -> int:
    value = load_toml(mer_a_path)["radiometry"]["prnu_seed"]
    assert TRUTH_FIELDS == {"radiometry": ("prnu_seed",)} and value == 20040104
    return value


@pytest.fixture(scope="module")
def inputs(mer_a):
    descent = constant_velocity_descent(mer_a, random_ground(np.random.default_rng(5)), np.random.default_rng(6))
    assert mer_a.radiometry.prnu_seed == 20040104          # the simulator's camera keeps its truth
    return EstimatorInputs(images=tuple(descent.images), image_times_s=np.array([m.time_s for m in descent.truth.images]),
                           measurements=descent.truth, camera=mer_a)


@pytest.fixture
def probe_module(tmp_path, monkeypatch):
    (tmp_path / "truth_probe.py").write_text(PROBE)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(tmp_path), str(Path(__file__).resolve().parents[2])]))
    yield tmp_path
    sys.modules.pop("truth_probe", None)


@pytest.mark.parametrize("isolate", [False, True], ids=["in-process", "isolated"])
def test_python_plugins_get_the_camera_without_the_prnu_seed(inputs, mer_a, probe_module, seed, isolate):
    spec = EstimatorSpec(name="probe", kind="python", callable="truth_probe:probe", isolate=isolate,
                         parameters={"seed": seed}, timeout_s=60.0)
    run = run_estimator("probe", build_estimator(spec), inputs)
    assert run.error == "" and run.output.reason == "design_only", (run.error, run.output)
    if not isolate:
        received = sys.modules["truth_probe"].SEEN[-1]
        with pytest.raises(AttributeError):
            received.radiometry.prnu_seed                   # noqa: B018 - reading it is the test
        design = mer_a.radiometry.model_dump()
        assert received.radiometry.model_dump() == {k: v for k, v in design.items() if k != "prnu_seed"}
        assert received.radiometry.prnu_sigma == mer_a.radiometry.prnu_sigma == 0.01
        assert received.width_px == mer_a.width_px and np.array_equal(received.model.a, mer_a.model.a)


def test_command_plugins_get_a_camera_file_without_the_prnu_seed(inputs, mer_a, tmp_path, seed):
    kept = tmp_path / "received_camera.toml"
    script = ("import json, shutil, sys; shutil.copy(sys.argv[1], sys.argv[3]); json.dump({'velocity_east_mps': None, "
              "'velocity_north_mps': None, 'valid': False, 'reason': 'copied'}, open(sys.argv[2], 'w'))")
    spec = EstimatorSpec(name="copy_camera", kind="command", argv=(sys.executable, "-c", script, "{camera}", "{output}",
                                                                    str(kept)), timeout_s=60.0)
    run = run_estimator("copy_camera", build_estimator(spec), inputs)
    assert run.error == "" and run.output.reason == "copied", run.error
    text = kept.read_text()
    assert "prnu_seed" not in text and str(seed) not in text
    with pytest.raises(ConfigError, match="prnu_seed"):
        load_camera(kept)                                   # the simulator could not even use it
    design = load_design_camera(kept)
    assert design.radiometry.model_dump() == {k: v for k, v in mer_a.radiometry.model_dump().items() if k != "prnu_seed"}
    assert design.timing == mer_a.timing and design.electronics == mer_a.electronics and design.optics == mer_a.optics
    assert np.allclose(design.model.c, mer_a.model.c) and np.allclose(design.model.r, mer_a.model.r)


def test_a_full_camera_file_loads_for_an_estimator_without_its_seed(mer_a_path):
    camera = load_design_camera(mer_a_path)
    assert not hasattr(camera.radiometry, "prnu_seed") and b"prnu_seed" not in pickle.dumps(camera)
