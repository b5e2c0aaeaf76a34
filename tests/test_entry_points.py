"""Every command line follows one convention (README, "Commands"): ``main(argv: list[str] | None = None) -> int``
in a module named for what the command does, run as ``python -m package.module``, ending in
``sys.exit(main())``; a package's ``__main__`` and the older module paths only call the new ``main``."""
from __future__ import annotations

import ast
import runpy
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("config_tables", "flight_interface", "file_formats", "simulator", "dimes_velocity", "estimators",
            "sitedata", "campaign", "benchmarks")

#: old path (scripts may run it) -> the command it runs now
OLD_PATHS = {
    "simulator": "simulator.render_example",
    "simulator.calibration": "simulator.calibrate_flat_field",
    "file_formats.planetary": "file_formats.planetary.inspect_files",
    "sitedata.edl.trajectories_cli": "sitedata.edl.trajectory_sets",
    "sitedata.terrain.mosaic": "sitedata.terrain.write_mosaics",
    "campaign.realism.terrain_stats_cli": "campaign.realism.measure_terrains",
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _main_guards() -> dict[str, tuple[Path, ast.If]]:
    """Module -> (file, its ``if __name__ == "__main__":`` block) of every project module that runs as a command."""
    found = {}
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            tree = ast.parse(path.read_text())
            for node in tree.body:
                if isinstance(node, ast.If) and "__name__" in ast.unparse(node.test) and "__main__" in ast.unparse(node.test):
                    found[_module_name(path)] = (path, node)
    return found


GUARDS = _main_guards()


def _main_definition(module: str) -> ast.FunctionDef | None:
    path, _ = GUARDS[module]
    tree = ast.parse(path.read_text())
    defined = next((node for node in tree.body if isinstance(node, ast.FunctionDef) and node.name == "main"), None)
    if defined is not None:
        return defined
    source = next((node.module for node in tree.body if isinstance(node, ast.ImportFrom)
                   and any(alias.name == "main" for alias in node.names)), None)
    if source is None:
        return None
    source_path = REPO.joinpath(*source.split(".")).with_suffix(".py")
    return next((node for node in ast.parse(source_path.read_text()).body
                 if isinstance(node, ast.FunctionDef) and node.name == "main"), None)


def test_the_commands_are_found():
    assert {"campaign.cli", "simulator.render_example", "sitedata.edl.trajectory_sets"} <= set(GUARDS), sorted(GUARDS)


@pytest.mark.parametrize("module", sorted(GUARDS))
def test_a_command_is_main_argv_returning_its_exit_status(module):
    """``if __name__ == "__main__": sys.exit(main())`` with ``main(argv: list[str] | None = None) -> int``; an old
    library path hands over with ``runpy.run_module`` to the command's own module."""
    _, guard = GUARDS[module]
    body = [ast.unparse(statement) for statement in guard.body]
    if module in OLD_PATHS and any("runpy.run_module" in line for line in body):
        assert any(f"'{OLD_PATHS[module]}'" in line for line in body), body
        return
    assert body == ["sys.exit(main())"], body
    main = _main_definition(module)
    assert main is not None, f"{module}: no main"
    arguments = main.args
    assert [a.arg for a in arguments.args] == ["argv"] and len(arguments.defaults) == 1, ast.unparse(main.args)
    assert ast.unparse(arguments.args[0].annotation) == "list[str] | None", ast.unparse(main.args)
    assert ast.unparse(arguments.defaults[0]) == "None" and ast.unparse(main.returns) == "int"


@pytest.mark.filterwarnings("ignore:.*found in sys.modules:RuntimeWarning")   # this process imported it already
@pytest.mark.parametrize("old, new", sorted(OLD_PATHS.items()))
def test_an_old_path_still_runs_the_command(old, new, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", [old, "--help"])
    with pytest.raises(SystemExit) as exited:
        runpy.run_module(old, run_name="__main__", alter_sys=True)
    assert exited.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: python -m {new} ")
