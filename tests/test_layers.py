"""The layers point one way: every import statement of the project (top level and inside functions) is read
with ``ast`` and checked against the allowed arrows below, plus: no import circles between modules, no
function-local import of a project module, and inside the simulator the scene stage imports nothing from
the detector stage.

    campaign                      (top: configuration, plan, run, store, report, realism; the CLI)
    sitedata        estimators    (simulator inputs | the estimator contract and plug-ins)
    simulator       dimes_velocity
    file_formats                  (every file format)
    flight_interface              (what flight and simulator legitimately share)
    config_tables                 (bottom: TOML -> validated tables, command lines, one-line errors)

Inside ``campaign`` the subpackages are layered too (:data:`CAMPAIGN_ALLOWED`, no circle between them):

    cli, commands   studies       (top: the command line, each command importing its stack when it runs |
                                   studies that run cases and read them back: calibration, ablation, tuning)
    run             report        (running cases on dask | reading stores for people; never each other)
    case            realism       (one case: inputs, computation, result rows | flight realism)
                    analysis      (sensitivity of stored outcomes to their inputs; designed-sweep indices)
    plan            store         (placing cases | the campaign store)
    configuration                 (bottom: the campaign, sweep and estimator files)
"""
from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

#: package -> the project packages it may import (besides itself)
ALLOWED = {
    "config_tables": set(),
    "flight_interface": {"config_tables"},
    "file_formats": {"config_tables", "flight_interface"},
    "simulator": {"config_tables", "flight_interface", "file_formats"},
    "dimes_velocity": {"config_tables", "flight_interface", "file_formats"},
    "estimators": {"config_tables", "flight_interface", "file_formats", "dimes_velocity"},
    "sitedata": {"config_tables", "flight_interface", "file_formats", "simulator"},
    "campaign": {"config_tables", "flight_interface", "file_formats", "simulator", "dimes_velocity", "estimators",
                 "sitedata"},
}
PROJECT = set(ALLOWED) | {"tests", "benchmarks"}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(REPO).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _sources() -> dict[str, Path]:
    return {_module_name(path): path for package in ALLOWED for path in sorted((REPO / package).rglob("*.py"))}


MODULES = _sources()


def _imports(module: str, path: Path) -> list[tuple[str, bool, int]]:
    """(imported project module, inside a function?, line) of every import statement of ``path``."""
    tree = ast.parse(path.read_text())
    in_function = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            in_function.update(id(child) for child in ast.walk(node) if child is not node)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([node.module] if node.module else []))
            # ``from package import module`` imports that module; ``from module import name`` the module
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base for alias in node.names]
        else:
            continue
        for target in targets:
            if target.split(".")[0] in PROJECT:
                found.append((target, id(node) in in_function, node.lineno))
    return found


GRAPH = {module: _imports(module, path) for module, path in MODULES.items()}


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_the_layers_below(package):
    offenders = [f"{module}:{line} imports {target}" for module, imports in GRAPH.items()
                 if module.split(".")[0] == package for target, _, line in imports
                 if target.split(".")[0] not in ALLOWED[package] | {package}]
    assert not offenders, offenders


def test_the_scene_stage_imports_nothing_from_the_detector_stage():
    offenders = [f"{module}:{line} imports {target}" for module, imports in GRAPH.items()
                 if module.startswith("simulator.scene.") or module == "simulator.scene"
                 for target, _, line in imports if target.startswith("simulator.detector")]
    assert not offenders, offenders


#: campaign subpackage -> the campaign subpackages it may import (besides itself); the modules directly in
#: ``campaign/`` (the command line) may import every subpackage.
CAMPAIGN_ALLOWED = {
    "configuration": set(),
    "plan": {"configuration"},
    "store": {"configuration"},
    "case": {"configuration", "plan", "store"},
    "realism": {"configuration"},
    "run": {"configuration", "plan", "store", "case"},
    "analysis": {"configuration", "store"},
    "report": {"configuration", "plan", "store", "case", "realism", "analysis"},
    "studies": {"configuration", "plan", "store", "case", "realism", "run", "report", "analysis"},
}


def _campaign_part(module: str) -> str | None:
    """The campaign subpackage of a campaign module (None for a module directly in ``campaign/``)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and f"campaign.{parts[1]}" in MODULES
                                          and MODULES[f"campaign.{parts[1]}"].name == "__init__.py") else None


def _campaign_arrows() -> list[tuple[str, str, str, int]]:
    """(importing subpackage, imported subpackage, importing module, line) of every campaign-internal import
    between two subpackages."""
    arrows = []
    for module, imports in GRAPH.items():
        if module.split(".")[0] != "campaign" or (source := _campaign_part(module)) is None:
            continue
        for target, _, line in imports:
            resolved = _resolve(target)
            if resolved and resolved.split(".")[0] == "campaign":
                part = _campaign_part(resolved)
                if part is not None and part != source:
                    arrows.append((source, part, module, line))
    return arrows


def test_every_campaign_subpackage_is_declared():
    parts = {_campaign_part(module) for module in MODULES if module.startswith("campaign.")} - {None}
    assert parts == set(CAMPAIGN_ALLOWED), parts ^ set(CAMPAIGN_ALLOWED)


def test_campaign_subpackages_import_only_the_layers_below():
    offenders = [f"{module}:{line} imports campaign.{target}" for source, target, module, line in _campaign_arrows()
                 if target not in CAMPAIGN_ALLOWED[source]]
    assert not offenders, offenders


def test_run_and_report_never_import_each_other():
    """Running cases and reading stores for people meet only below (campaign.case, campaign.store) and in the
    command line: neither direction is allowed, at top level or inside a function."""
    offenders = [f"{module}:{line} imports campaign.{target}" for source, target, module, line in _campaign_arrows()
                 if {source, target} == {"run", "report"}]
    assert not offenders, offenders
    assert "report" not in CAMPAIGN_ALLOWED["run"] and "run" not in CAMPAIGN_ALLOWED["report"]


def test_no_circle_between_campaign_subpackages():
    edges = defaultdict(set)
    for source, target, _, _ in _campaign_arrows():
        edges[source].add(target)
    for start in sorted(edges):
        reached, pending = set(), list(edges[start])
        while pending:
            part = pending.pop()
            if part not in reached:
                reached.add(part)
                pending += edges[part]
        assert start not in reached, f"campaign.{start} reaches itself through {sorted(reached)}"


#: Modules allowed function-local project imports, and why.
LAZY_BY_DESIGN = {
    "campaign.commands": "each command loads its own stack when it runs: a read-only command only what it reads",
    "dimes_velocity": "DimesEstimator and estimate_velocity load the estimator (its compiled passes: numba, which "
                      "imports scipy) on first use: reading an estimator's table (dimes_velocity.config) loads none",
    "simulator.off_nominal.dust": "the dust map's compiled pass (dust_pairs: numba, which imports scipy) loads when a "
                                  "map is made: declaring [scene.off_nominal] imports the particle types only",
    "simulator.off_nominal.moving_shadows": "the ground map (its compiled passes) loads when shadows are placed or "
                                            "drawn: declaring [scene.off_nominal] loads no numba",
    "simulator.scene.ground_mapping": "the fused node-grid passes (node_grid_fused: numba) load with the first ground "
                                      "map: the atmosphere's table, declared through scene_config, imports this module",
}


def test_no_function_local_import_of_a_project_module():
    offenders = [f"{module}:{line} imports {target}" for module, imports in GRAPH.items()
                 for target, local, line in imports if local and module not in LAZY_BY_DESIGN]
    assert not offenders, offenders


def _type_checking_lines(path: Path) -> set[int]:
    """Lines of the imports under ``if TYPE_CHECKING:`` (read by the type checker only, never run)."""
    return {child.lineno for node in ast.walk(ast.parse(path.read_text())) if isinstance(node, ast.If)
            and getattr(node.test, "id", getattr(node.test, "attr", None)) == "TYPE_CHECKING"
            for statement in node.body for child in ast.walk(statement) if isinstance(child, (ast.Import, ast.ImportFrom))}


def test_the_command_line_imports_only_light_modules_at_start():
    """`campaign` imports each command's stack in its function: at start-up only these light modules."""
    light = {_resolve(target) for module in ("campaign.cli", "campaign.commands")
             for target, local, line in GRAPH[module]
             if not local and line not in _type_checking_lines(MODULES[module])}
    assert light <= {"campaign.commands", "campaign.configuration.paths", "campaign.configuration.schemas",
                     "campaign.run.faults", "campaign.run.interrupts", "campaign.store.errors", "campaign.store.lock",
                     "config_tables.command_line", "config_tables.errors"}, light


def _resolve(target: str) -> str | None:
    while target and target not in MODULES:
        target = target.rpartition(".")[0]
    return target or None


def test_no_import_circles():
    edges = defaultdict(set)
    for module, imports in GRAPH.items():
        for target, _local, _ in imports:
            resolved = _resolve(target)
            if resolved and resolved != module:
                edges[module].add(resolved)
    state: dict[str, int] = {}
    circles = []

    def visit(module: str, trail: list[str]) -> None:
        state[module] = 1
        for nxt in sorted(edges[module]):
            if state.get(nxt) == 1:
                circles.append(trail[trail.index(nxt):] + [nxt] if nxt in trail else [module, nxt])
            elif nxt not in state:
                visit(nxt, trail + [nxt])
        state[module] = 2

    for module in sorted(MODULES):
        if module not in state:
            visit(module, [module])
    assert not circles, circles


def test_the_checker_sees_a_forbidden_arrow(tmp_path):
    """The rule check is live: an estimator module importing the simulator is found."""
    path = tmp_path / "probe.py"
    path.write_text("from simulator.scene.terrain import Terrain\n\ndef f():\n    import campaign.cli\n")
    found = _imports("dimes_velocity.probe", path)
    assert ("simulator.scene.terrain", False, 1) in found and ("campaign.cli", True, 4) in found
    assert not {target.split(".")[0] for target, _, _ in found} <= ALLOWED["dimes_velocity"]


#: what a read-only command never loads: running cases (dask, the case computation, planning) and the simulator,
#: estimators and reference estimator behind them
RUN_STACK = ("campaign.run", "campaign.case", "campaign.plan", "simulator.descent_image", "simulator.scene.radiance",
             "estimators", "dimes_velocity")


def _closure(starts: set[str]) -> set[str]:
    """The project modules ``starts`` import when they load (top-level imports, followed, except the type
    checker's; the packages on the way)."""
    seen: set[str] = set()
    pending = list(starts)
    while pending:
        module = pending.pop()
        if module in seen or module not in MODULES:
            continue
        seen.add(module)
        parts = module.split(".")
        pending += [".".join(parts[:end]) for end in range(1, len(parts))]
        checker_only = _type_checking_lines(MODULES[module])
        pending += [resolved for target, local, line in GRAPH[module]
                    if not local and line not in checker_only and (resolved := _resolve(target))]
    return seen


@pytest.mark.parametrize("command", ["status", "verify", "table"])
def test_a_read_only_command_loads_only_what_it_reads(command):
    """`campaign status|verify|table DIR` import the store (and the table's report modules) when they run, never
    the run stack: the function's own imports and everything they load."""
    tree = ast.parse(MODULES["campaign.commands"].read_text())
    function = next(node for node in tree.body if isinstance(node, ast.FunctionDef) and node.name == command)
    lines = {node.lineno for node in ast.walk(function) if isinstance(node, (ast.Import, ast.ImportFrom))}
    starts = {_resolve(target) for target, _, line in GRAPH["campaign.commands"] if line in lines} - {None}
    starts |= _closure({"campaign.cli"})          # what the command line itself loads at start
    loaded = _closure({module for module in starts if module})
    # the command line maps RunStopped to its exit code and installs the stop-signal handlers (stdlib only)
    light = {"campaign.run", "campaign.run.faults", "campaign.run.interrupts"}
    assert loaded and not [module for module in loaded - light if module.startswith(RUN_STACK)], sorted(loaded)
