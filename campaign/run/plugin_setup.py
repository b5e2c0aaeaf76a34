"""Estimator plug-ins on the workers: their code shipped to every worker, and a plug-in that cannot be set
up there stopping the run instead of failing cases.

What is shipped (:func:`shipped_code`): for every ``kind = "python"`` estimator, the *top-level* module or
package of its ``callable`` as the driver imports it (``mine`` of ``mine:estimate``, the whole ``pkg/``
directory of ``pkg.sub.mod:estimate``), zipped (``__pycache__`` and ``*.pyc`` left out), unless it is one
of this project's packages or sits at the top of the Python installation's standard library or
``site-packages``: installed packages are the workers' environment, never shipped (a module found through
an ``[[estimators]]`` entry's ``path`` is shipped wherever it lives). Neither is a namespace package (no
``__init__.py``). A compiled extension module cannot be
shipped (a zip cannot hold an importable ``.so``); install it on the workers.

How (:func:`ship_plugin_code`): each zip is registered with the scheduler as a dask worker plug-in
(:class:`ShippedPlugin`, a :class:`distributed.diagnostics.plugin.UploadFile`): every worker, and every
worker that joins later, writes it into its local directory, puts it on ``sys.path`` and imports the
module, whatever the worker's current directory and ``PYTHONPATH``. A module is registered under one plug-in
name, so a second submit replaces the code of the first: the worker forgets the old modules and zip first.

Set-up errors (:class:`PluginSetupError`, a :class:`~campaign.run.faults.InfrastructureError`): a shipped
module that does not import on a worker (a dependency missing there), or an estimator that cannot be built
on a worker (:class:`estimators.plugins.EstimatorSetupError`: module, reference parameters, a command's
program) stop the run with one line naming the estimator, the worker's address, the error and the fix;
nothing is recorded for the cases it could not run, so the next submit runs them.
"""
from __future__ import annotations

import hashlib
import importlib
import io
import os
import socket
import sys
import sysconfig
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

from distributed import get_worker
from distributed.diagnostics.plugin import UploadFile

from campaign.configuration.code_identity import PROJECT_PACKAGES
from campaign.run.faults import InfrastructureError
from estimators.entries import EstimatorSpec


class PluginSetupError(InfrastructureError):
    """An estimator plug-in cannot be loaded or started on a worker (one line: estimator, worker, error, fix)."""


def worker_address() -> str:
    """The dask address of the worker running the current task (``host:pid`` outside a worker)."""
    try:
        return get_worker().address
    except ValueError:
        return f"{socket.gethostname()}:{os.getpid()}"


@dataclass(frozen=True)
class ShippedCode:
    """One plug-in's top-level module or package, zipped.

    Attributes
    ----------
    module : str
        Top-level module name (``mine``, ``pkg``).
    estimators : tuple of str
        The estimators whose callable lives in it.
    imports : tuple of str
        The callables' modules (``pkg.sub.mod``), imported by every worker when the code arrives.
    source : str
        The file (a ``.py``) or package directory it was zipped from.
    data : bytes
        The zip archive (the module at its root).
    """

    module: str
    estimators: tuple[str, ...]
    source: str
    data: bytes
    imports: tuple[str, ...] = ()

    @property
    def file_name(self) -> str:
        return f"moc2dimes-plugin-{self.module}-{hashlib.sha256(self.data).hexdigest()[:12]}.zip"


def _installed_roots() -> tuple[Path, ...]:
    paths = sysconfig.get_paths()
    roots = {Path(paths[key]).resolve() for key in ("stdlib", "platstdlib", "purelib", "platlib") if key in paths}
    return tuple(sorted(roots))


def _is_installed(source: Path) -> bool:
    """Whether the module or package at ``source`` is one of the Python installation's own: it sits at the top
    of the standard library or of ``site-packages`` (every worker of the environment imports it). A module
    deeper inside (e.g. a plug-in beside a campaign file in an installed package's data, imported through an
    ``[[estimators]]`` entry's ``path``) is not on the workers' ``sys.path``: it is shipped."""
    root = source.resolve().parent
    return root.name in ("site-packages", "dist-packages") or root in _installed_roots()


def _zip(source: Path, module: str) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as archive:
        if source.is_file():
            archive.writestr(zipfile.ZipInfo(f"{module}.py", (1980, 1, 1, 0, 0, 0)), source.read_bytes())
        else:
            for path in sorted(source.rglob("*")):
                if path.is_dir() or "__pycache__" in path.parts or path.suffix == ".pyc":
                    continue
                name = f"{module}/{path.relative_to(source).as_posix()}"
                archive.writestr(zipfile.ZipInfo(name, (1980, 1, 1, 0, 0, 0)), path.read_bytes())
    return buffer.getvalue()


def shipped_code(specs: list[EstimatorSpec] | tuple[EstimatorSpec, ...]) -> list[ShippedCode]:
    """The plug-in code to ship for ``specs`` (module docstring), imported as the driver imports it.
    Modules the driver cannot import are skipped: their estimators fail set-up where they are built."""
    users: dict[str, list[str]] = {}
    modules: dict[str, set[str]] = {}
    for spec in specs:
        if spec.kind == "python":
            module_name = spec.callable.split(":")[0]
            names = users.setdefault(module_name.split(".")[0], [])
            if spec.name not in names:
                names.append(spec.name)
            modules.setdefault(module_name.split(".")[0], set()).add(module_name)
    shipped = []
    for module, names in sorted(users.items()):
        if module in PROJECT_PACKAGES:
            continue
        try:
            __import__(module)
        except BaseException:  # noqa: B036 -- a plug-in's import may raise anything; its build reports it
            continue
        origin = getattr(sys.modules[module], "__file__", None)
        if not origin or not origin.endswith(".py") or not Path(origin).is_file():
            continue
        source = Path(origin).parent if Path(origin).name == "__init__.py" else Path(origin)
        if _is_installed(source):
            continue
        shipped.append(ShippedCode(module, tuple(names), str(source), _zip(source, module),
                                   tuple(sorted(modules[module]))))
    return shipped


class ShippedPlugin(UploadFile):
    """dask's UploadFile for one plug-in zip: a worker that cannot import the module raises
    :class:`PluginSetupError` (so does the driver's registration)."""

    def __init__(self, code: ShippedCode, path: str):
        super().__init__(path, load=True)
        self.module = code.module
        self.estimators = code.estimators
        self.imports = code.imports

    async def setup(self, worker):
        # a previous version of the plug-in on this worker (an earlier submit to a long-lived cluster) is
        # forgotten first: its modules and its zip on sys.path, so every module is run from this zip
        for name in [name for name in sys.modules if name == self.module or name.startswith(f"{self.module}.")]:
            del sys.modules[name]
        sys.path[:] = [entry for entry in sys.path if not Path(entry).name.startswith(f"moc2dimes-plugin-{self.module}-")]
        importlib.invalidate_caches()
        try:
            await super().setup(worker)
            for name in self.imports:
                importlib.import_module(name)
        except BaseException as exc:  # noqa: B036 -- the module's import may raise anything, SystemExit included
            text = " ".join(f"{type(exc).__name__}: {exc}".split())[:300]
            modules = ", ".join(map(repr, self.imports or (self.module,)))
            raise PluginSetupError(
                f"estimator {', '.join(self.estimators)} cannot be set up on worker {worker.address}: module "
                f"{modules} (shipped) does not import there: {text}; install what it imports on every worker "
                "(only the plug-in's own top-level module or package is shipped)") from None


def ship_plugin_code(client, specs: list[EstimatorSpec] | tuple[EstimatorSpec, ...]) -> list[ShippedCode]:
    """Register every plug-in's code (:func:`shipped_code`) with the cluster of ``client``; return what was
    shipped. Raises PluginSetupError (one line) when a worker cannot import a shipped module."""
    shipped = shipped_code(specs)
    if not shipped:
        return shipped
    with tempfile.TemporaryDirectory(prefix="moc2dimes-plugins-") as directory:
        for code in shipped:
            path = Path(directory) / code.file_name
            path.write_bytes(code.data)
            client.register_plugin(ShippedPlugin(code, str(path)), name=f"moc2dimes-plugin-{code.module}")
    return shipped
