"""Code identity: which code computes a case's result, read from the code itself.

The configuration hash includes a digest of every module that can change a case's result rows
(:func:`code_digest`), so results of different code are never mixed in one store and a sweep point is
reused only when the code that computed it is unchanged. Which modules those are is not a hand-kept list:
it is the *import closure* of the case computation (:data:`CASE_MODULES`), read statically with
:mod:`ast` from the source files:

* every ``import a.b`` and ``from a.b import c`` (``c`` a module or a name; relative forms too), at the
  top level or inside functions (not under ``if TYPE_CHECKING:``), that names a module of the project
  packages (:data:`PROJECT_PACKAGES`); third-party and standard-library modules are not followed;
* every string constant that is exactly the dotted name of a project module (a module started as
  ``python -m estimators.run_python`` or loaded by ``importlib.import_module("pkg.mod")``);
* the ``__init__`` of every package on the way (importing ``a.b.c`` runs ``a`` and ``a.b`` first).

The closure does not descend into :data:`PRESENTATION_PACKAGES` (``campaign.report``: tables, plots and the
example PNGs a worker draws of a case; they never change a result row). The digest is the sha256 over the
closure's files, sorted by path relative to the source root, each path and its contents.

The estimator plug-ins named by a campaign's ``[[estimators]]`` are covered too: a ``kind = "python"``
callable inside the project packages adds its module to the closure's starting points (so its imports
are followed: :func:`plugin_modules`), and every plug-in's own files (a python callable's module file as
found on ``sys.path``, a command's program and script arguments) are hashed by
:func:`campaign.configuration.estimators.estimator_code_digests`.

Reading the imports is an :mod:`ast` parse of every file of the closure (~0.4 s a process, paid by every
``campaign`` command). The parse's result, the set of dotted names a source names, is kept on disk
(:func:`imports_cache_path`) keyed by the sha256 of the source's bytes *and* of this module's own source
(the rules that read it), so an entry can only be reused for the very bytes it was read from under the
very same rules; a missing, unreadable or malformed cache file is ignored (and rewritten), and a read-only
cache directory only costs the parse. The digest itself is always computed from the files' bytes.

The data that change results are hashed by :func:`campaign.configuration.campaign_file.hashed_content`:
the site table as resolved content, the camera TOML, trajectory set, terrain files and sidecars by their bytes.
"""
from __future__ import annotations

import ast
import functools
import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path

#: the top-level packages whose modules are followed (everything else is a dependency, not project code)
PROJECT_PACKAGES = ("config_tables", "flight_interface", "file_formats", "simulator", "dimes_velocity", "estimators", "sitedata",
                    "campaign")
#: where a case's result is computed (a module that does not exist is skipped)
CASE_MODULES = ("campaign.case.compute", "campaign.run.worker")
#: packages that only present results (the closure stops at them)
PRESENTATION_PACKAGES = ("campaign.report",)
#: the source root holding the project packages
SOURCE_ROOT = Path(__file__).resolve().parents[2]


def module_file(name: str, root: Path = SOURCE_ROOT) -> Path | None:
    """The source file of project module ``name`` under ``root`` (a package's ``__init__.py``), or None."""
    if name.split(".")[0] not in PROJECT_PACKAGES:
        return None
    base = root.joinpath(*name.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


def imported_modules(name: str, path: Path, root: Path = SOURCE_ROOT) -> set[str]:
    """The project modules module ``name`` (source ``path``) imports or names, anywhere in its source."""
    candidates = _IMPORTS_CACHE.named_modules(name, path.name == "__init__.py", path.read_bytes())
    return {module for module in candidates if module_file(module, root) is not None}


def imports_cache_path() -> Path:
    """The on-disk cache of :func:`_named_modules`' results: ``code-imports-py3.N.json`` in ``$MOC2DIMES_CACHE``
    (``~/.cache/moc2dimes`` when unset: the same directory as the terrain strips' cache)."""
    directory = os.environ.get("MOC2DIMES_CACHE")
    base = Path(directory) if directory else Path.home() / ".cache" / "moc2dimes"
    return base / f"code-imports-py{sys.version_info[0]}.{sys.version_info[1]}.json"


class _ImportsOnDisk:
    """:func:`_named_modules` behind the on-disk cache of the module doc (one per process)."""

    def __init__(self) -> None:
        self.path: Path | None = None
        self.entries: dict[str, list[str]] = {}
        self.used: set[str] = set()
        self.added = False

    def _load(self) -> None:
        path = imports_cache_path()
        if path == self.path:
            return
        self.path, self.entries, self.used, self.added = path, {}, set(), False
        try:
            loaded = json.loads(path.read_text())
        except (OSError, ValueError):
            return
        if isinstance(loaded, dict):
            self.entries = {key: value for key, value in loaded.items()
                            if isinstance(value, list) and all(isinstance(item, str) for item in value)}

    def named_modules(self, name: str, is_package: bool, source: bytes) -> frozenset[str]:
        self._load()
        key = f"{_RULES_DIGEST}:{hashlib.sha256(source).hexdigest()}:{name}:{int(is_package)}"
        self.used.add(key)
        cached = self.entries.get(key)
        if cached is not None:
            return frozenset(cached)
        found = _named_modules(name, is_package, source)
        self.entries[key] = sorted(found)
        self.added = True
        return found

    def save(self) -> None:
        """Write the entries when this process added any (atomically; a cache that cannot be written is
        skipped). Past :data:`IMPORTS_CACHE_ENTRIES` entries (sources edited many times), only those this
        process used are kept."""
        if not self.added or self.path is None:
            return
        if len(self.entries) > IMPORTS_CACHE_ENTRIES:
            self.entries = {key: value for key, value in self.entries.items() if key in self.used}
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            handle, temporary = tempfile.mkstemp(dir=self.path.parent, prefix=".code-imports-", suffix=".tmp")
            with os.fdopen(handle, "w") as stream:
                json.dump(self.entries, stream, sort_keys=True)
            os.replace(temporary, self.path)
            self.added = False
        except OSError:
            pass


#: entries of the on-disk import cache above which a write keeps only those the writing process used
IMPORTS_CACHE_ENTRIES = 4096
#: sha256 of this module's source: the rules a cached import list was read with
_RULES_DIGEST = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()
_IMPORTS_CACHE = _ImportsOnDisk()


@functools.lru_cache(maxsize=1024)
def _named_modules(name: str, is_package: bool, source: bytes) -> frozenset[str]:
    """Every dotted name ``source`` imports (``from a import b``: both ``a`` and ``a.b``) or holds as a
    string constant, whether or not it is a module (cached by content: parsing is most of the work)."""
    tree = ast.parse(source)
    package = name if is_package else name.rpartition(".")[0]
    type_checking_only = {child for node in ast.walk(tree) if isinstance(node, ast.If) and _type_checking(node.test)
                          for statement in node.body for child in ast.walk(statement)}
    found: set[str] = set()
    for node in ast.walk(tree):
        if node in type_checking_only:
            continue
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: max(0, len(package.split(".")) - node.level + 1)]
                base = ".".join(anchor + ([node.module] if node.module else []))
            found.add(base)
            # ``from package import module`` imports that module too
            found.update(f"{base}.{alias.name}" for alias in node.names)
        elif (isinstance(node, ast.Constant) and isinstance(node.value, str) and "." in node.value
              and node.value.isascii() and all(part.isidentifier() for part in node.value.split("."))):
            found.add(node.value)
    return frozenset(found)


def _type_checking(test: ast.expr) -> bool:
    """``if TYPE_CHECKING:`` / ``if typing.TYPE_CHECKING:`` (imports only the type checker runs)."""
    return ((isinstance(test, ast.Name) and test.id == "TYPE_CHECKING")
            or (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"))


def _presentation(name: str) -> bool:
    return any(name == package or name.startswith(package + ".") for package in PRESENTATION_PACKAGES)


def import_closure(starts: tuple[str, ...] = CASE_MODULES, root: Path = SOURCE_ROOT) -> dict[str, Path]:
    """Project module name -> source file of every module reachable from ``starts`` (missing starts
    skipped), with the ``__init__`` of each package on the way; presentation packages are not entered."""
    closure: dict[str, Path] = {}
    pending = [name for name in starts if module_file(name, root) is not None]
    while pending:
        name = pending.pop()
        if name in closure or _presentation(name):
            continue
        path = module_file(name, root)
        if path is None:
            continue
        closure[name] = path
        parts = name.split(".")
        pending += [".".join(parts[:end]) for end in range(1, len(parts))]
        pending += sorted(imported_modules(name, path, root))
    _IMPORTS_CACHE.save()
    return dict(sorted(closure.items()))


def closure_digest(starts: tuple[str, ...] = CASE_MODULES, root: Path = SOURCE_ROOT) -> str:
    """sha256 over the files of :func:`import_closure` (path relative to ``root``, then contents, sorted
    by path). Not cached: see :func:`code_digest`."""
    digest = hashlib.sha256()
    for path in sorted(path.relative_to(root).as_posix() for path in import_closure(starts, root).values()):
        digest.update(path.encode() + b"\0")
        digest.update(hashlib.sha256((root / path).read_bytes()).hexdigest().encode())
    return digest.hexdigest()


def plugin_modules(specs) -> tuple[str, ...]:
    """The project modules of the ``kind = "python"`` estimator plug-ins among ``specs`` (sorted; plug-ins
    outside the project packages are hashed by their module file alone)."""
    names = {spec.callable.split(":")[0] for spec in specs if spec.kind == "python"}
    return tuple(sorted(name for name in names if module_file(name) is not None))


@functools.lru_cache(maxsize=16)
def code_digest(plugins: tuple[str, ...] = ()) -> str:
    """The digest of the code that computes a case's result in this checkout: the import closure of
    :data:`CASE_MODULES` plus the project modules ``plugins`` (see :func:`plugin_modules`). Cached per
    process (the sources do not change under a running service)."""
    return closure_digest(CASE_MODULES + tuple(plugins), SOURCE_ROOT)
