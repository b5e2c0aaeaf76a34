"""Code identity from the code itself: the configuration hash's code digest covers the import closure of
the case computation (read with ``ast`` from the sources) plus the estimator plug-ins' files, so editing
any module that can change a case's result changes the hash, and editing a report module does not."""
from __future__ import annotations

import json
import shutil
import sys
import tomllib
from pathlib import Path

import pytest

from campaign.configuration import code_identity
from campaign.configuration.campaign_file import campaign_config_from_data
from campaign.configuration.code_identity import (
    CASE_MODULES,
    PROJECT_PACKAGES,
    SOURCE_ROOT,
    closure_digest,
    code_digest,
    import_closure,
    plugin_modules,
)

REPO = Path(__file__).resolve().parents[3]
GUSEV = REPO / "sitedata" / "gusev.toml"
PLUGINS = REPO / "tests" / "plugins"


def _python_sources_only(directory, names):
    return [name for name in names if name == "__pycache__"
            or (not name.endswith(".py") and not (Path(directory) / name).is_dir())]


@pytest.fixture(scope="module")
def source_copy(tmp_path_factory):
    """The project packages' Python sources copied to a temporary root, and their digest there."""
    root = tmp_path_factory.mktemp("source")
    for package in PROJECT_PACKAGES:
        shutil.copytree(REPO / package, root / package, ignore=_python_sources_only)
    return root, closure_digest(root=root)


def test_closure_is_the_case_computation_and_what_it_imports():
    closure = import_closure()
    assert SOURCE_ROOT == REPO
    for module in ("campaign.case.compute", "campaign.plan.coverage", "campaign.store.case_files",
                   "simulator.descent_image", "simulator.scene.radiance", "dimes_velocity.estimator",
                   "estimators.plugins", "estimators.run_python",       # started as ``python -m`` by a string
                   "file_formats.measurements_json", "file_formats.flat_field_files", "file_formats.planetary.pds3",
                   "sitedata.sites", "flight_interface.camera", "campaign", "campaign.run", "simulator.scene"):
        assert module in closure, module
    if (REPO / "campaign" / "run" / "worker.py").is_file():
        assert "campaign.run.worker" in closure
    assert "campaign.cli" not in closure
    assert not [module for module in closure if module.startswith(("campaign.report", "campaign.realism"))]
    assert all(path == SOURCE_ROOT.joinpath(*module.split(".")).with_suffix(".py")
               or path == SOURCE_ROOT.joinpath(*module.split("."), "__init__.py") for module, path in closure.items())


@pytest.mark.parametrize("relative", [
    "campaign/case/compute.py", "campaign/plan/coverage.py", "campaign/store/case_files.py",
    "file_formats/measurements_json.py", "file_formats/planetary/pds3.py", "simulator/descent_image.py",
    "simulator/scene/__init__.py", "dimes_velocity/estimator.py", "estimators/run_python.py",
    "sitedata/terrain/synthetic_terrain.py", "flight_interface/camera.py",
])
def test_editing_a_module_of_the_closure_changes_the_digest(source_copy, relative):
    root, before = source_copy
    path = root / relative
    original = path.read_bytes()
    try:
        path.write_bytes(original + b"\n# edited\n")
        assert closure_digest(root=root) != before
    finally:
        path.write_bytes(original)


@pytest.mark.parametrize("relative", ["campaign/report/markdown.py", "campaign/report/plots.py", "campaign/cli.py",
                                      "estimators/phase_correlation.py"])
def test_editing_a_module_outside_the_closure_keeps_the_digest(source_copy, relative):
    root, before = source_copy
    path = root / relative
    original = path.read_bytes()
    try:
        path.write_bytes(original + b"\n# edited\n")
        assert closure_digest(root=root) == before
    finally:
        path.write_bytes(original)


def test_a_project_plugin_module_joins_the_closure_with_its_imports(source_copy):
    root, _ = source_copy
    starts = CASE_MODULES + ("estimators.phase_correlation",)
    assert "estimators.phase_correlation" in import_closure(starts, root)
    path = root / "estimators" / "phase_correlation.py"
    original = path.read_bytes()
    before = closure_digest(starts, root)
    try:
        path.write_bytes(original + b"\n# edited\n")
        assert closure_digest(starts, root) != before
    finally:
        path.write_bytes(original)


def test_every_import_form_is_followed_and_the_worker_joins_when_it_exists(tmp_path):
    files = {
        "campaign/__init__.py": "",
        "campaign/run/__init__.py": "",
        "campaign/case/__init__.py": "",
        "campaign/case/compute.py": ("import numpy\nfrom typing import TYPE_CHECKING\nfrom ..run import faults\n"
                                 "if TYPE_CHECKING:\n    import campaign.run.unused\n\n"
                                 "def run():\n    from campaign.plan import coverage\n"),
        "campaign/run/faults.py": "from ..store.case_files import write\n",
        "campaign/run/unused.py": "",
        "campaign/plan/__init__.py": "",
        "campaign/plan/coverage.py": "import simulator.scene.terrain as terrain\n",
        "campaign/store/__init__.py": "",
        "campaign/store/case_files.py": "write = print\n",
        "campaign/report/__init__.py": "",
        "campaign/report/plots.py": "import campaign.run.unused\n",
        "simulator/__init__.py": "",
        "simulator/scene/__init__.py": "",
        "simulator/scene/terrain.py": "",
    }
    for relative, text in files.items():
        (tmp_path / relative).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / relative).write_text(text)
    expected = {"campaign", "campaign.case", "campaign.case.compute", "campaign.run", "campaign.run.faults", "campaign.store",
                "campaign.store.case_files", "campaign.plan", "campaign.plan.coverage", "simulator", "simulator.scene",
                "simulator.scene.terrain"}
    assert set(import_closure(root=tmp_path)) == expected
    (tmp_path / "campaign/run/worker.py").write_text("from campaign.report import plots\n")
    assert set(import_closure(root=tmp_path)) == expected | {"campaign.run.worker"}


def _config(estimators: list[dict]):
    data = tomllib.loads(GUSEV.read_text())
    data["estimators"] = estimators
    return campaign_config_from_data(data, GUSEV, source="test.toml")


def test_editing_a_python_plugin_file_changes_the_configuration_hash(tmp_path, monkeypatch):
    module = "code_identity_plugin"
    shutil.copy(PLUGINS / "python_estimators.py", tmp_path / f"{module}.py")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.delitem(sys.modules, module, raising=False)
    entries = [{"name": "dimes", "kind": "reference"},
               {"name": "imu", "kind": "python", "callable": f"{module}:imu_minus_bias"}]
    first = _config(entries).config_hash
    assert _config(entries).config_hash == first
    with open(tmp_path / f"{module}.py", "a") as handle:
        handle.write("\n# a changed plug-in\n")
    assert _config(entries).config_hash != first
    assert _config([{"name": "dimes", "kind": "reference"}]).config_hash != first
    sys.modules.pop(module, None)


def test_a_project_plugin_changes_the_code_digest():
    specs = _config([{"name": "dimes", "kind": "reference"},
                     {"name": "pc", "kind": "python", "callable": "estimators.phase_correlation:estimate"}]).estimators
    assert plugin_modules(specs) == ("estimators.phase_correlation",)
    assert code_digest(plugin_modules(specs)) != code_digest()


def _fresh_process_state(monkeypatch, cache_dir: Path) -> None:
    """A process that has read nothing yet: the on-disk cache in ``cache_dir``, no parse cached in memory."""
    monkeypatch.setenv("MOC2DIMES_CACHE", str(cache_dir))
    monkeypatch.setattr(code_identity, "_IMPORTS_CACHE", code_identity._ImportsOnDisk())
    code_identity._named_modules.cache_clear()


def test_the_import_lists_kept_on_disk_give_the_same_closure_without_parsing(source_copy, tmp_path, monkeypatch):
    """A second process reads the closure's import lists from the cache (no ``ast`` parse) and gets the same
    closure and digest; an edited source misses the cache (its key is its bytes) and is parsed again, so a
    new import in it joins the closure; a malformed cache file is ignored and rewritten."""
    root, before = source_copy
    _fresh_process_state(monkeypatch, tmp_path)
    cold = import_closure(root=root)
    assert code_identity.imports_cache_path().is_file()

    _fresh_process_state(monkeypatch, tmp_path)
    real_parse = code_identity.ast.parse

    def no_parse(*args, **kwargs):
        raise AssertionError("parsed although the cache holds this source")
    monkeypatch.setattr(code_identity.ast, "parse", no_parse)
    assert import_closure(root=root) == cold and closure_digest(root=root) == before

    edited = root / "campaign" / "case" / "compute.py"
    original = edited.read_bytes()
    try:
        edited.write_bytes(original + b"\nimport campaign.report.markdown as _edited\nimport campaign.cli\n")
        with pytest.raises(AssertionError, match="parsed although"):
            import_closure(root=root)
        monkeypatch.setattr(code_identity.ast, "parse", real_parse)
        assert "campaign.cli" in import_closure(root=root) and "campaign.cli" not in cold
    finally:
        edited.write_bytes(original)

    code_identity.imports_cache_path().write_text("{not json")
    _fresh_process_state(monkeypatch, tmp_path)
    assert import_closure(root=root) == cold
    assert isinstance(json.loads(code_identity.imports_cache_path().read_text()), dict)


def test_a_cached_import_list_is_bound_to_the_rules_that_read_it(source_copy, tmp_path, monkeypatch):
    """Entries written under other rules (another version of this module) are never used: a cache whose
    every list claims ``campaign.cli`` does not put it in the closure once the rules' digest differs."""
    root, _ = source_copy
    _fresh_process_state(monkeypatch, tmp_path)
    cold = import_closure(root=root)
    path = code_identity.imports_cache_path()
    poisoned = {key: value + ["campaign.cli"] for key, value in json.loads(path.read_text()).items()}
    path.write_text(json.dumps(poisoned))
    _fresh_process_state(monkeypatch, tmp_path)
    assert "campaign.cli" in import_closure(root=root)          # the same rules: the cache is believed
    _fresh_process_state(monkeypatch, tmp_path)
    monkeypatch.setattr(code_identity, "_RULES_DIGEST", "0" * 64)
    assert import_closure(root=root) == cold
