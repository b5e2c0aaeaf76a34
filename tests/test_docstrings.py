"""Every public callable of the library packages has a numpydoc docstring (scikit-image style).

Checked with :func:`numpydoc.validate.validate` on each public function, method and class defined in a
module of the packages below (names without a leading ``_``, modules too):

* functions and methods: a docstring (GL08), every parameter documented under ``Parameters`` (PR01), none
  documented that the signature lacks (PR02), a ``Returns`` section when the body returns a value (RT01),
  a ``Yields`` section for a generator (YD01);
* classes: a docstring; a class with its own ``__init__`` documents that signature under ``Parameters``
  (PR01, PR02); a dataclass documents each field under ``Parameters`` or ``Attributes``; a configuration
  model (pydantic) documents each field by the docstring below it (its JSON Schema description).

Properties are documented by a one-line docstring (GL08 only). Form (summary line, blank line after it) is
ruff's pydocstyle rules (``D``, numpy convention; ``[tool.ruff.lint]`` in pyproject.toml).

Run one package: ``python -m pytest -n 0 -q tests/test_docstrings.py -k simulator``.
"""
from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
import warnings
from collections.abc import Iterator, Mapping

import numpydoc.validate as numpydoc_validate
import pytest
from numpydoc.docscrape import NumpyDocString
from pydantic import BaseModel

#: The library packages held to the rule (campaign/, sitedata/, file_formats/, tests/ and benchmarks/ are not).
PACKAGES = ("config_tables", "flight_interface", "estimators", "dimes_velocity", "simulator")
#: numpydoc error codes that fail the test for a function or method.
FUNCTION_CODES = frozenset({"GL08", "PR01", "PR02", "RT01", "YD01"})
#: ... for a class with its own ``__init__``.
CLASS_CODES = frozenset({"GL08", "PR01", "PR02"})


def _modules(package: str) -> Iterator[str]:
    root = importlib.import_module(package)
    yield package
    for info in pkgutil.walk_packages(root.__path__, prefix=package + "."):
        if not any(part.startswith("_") and part != "__main__" for part in info.name.split(".")):
            yield info.name


def _public(namespace: Mapping[str, object], module: str) -> Iterator[tuple[str, object]]:
    for name, value in namespace.items():
        if name.startswith("_"):
            continue
        function = value.__func__ if isinstance(value, (classmethod, staticmethod)) else value
        function = inspect.unwrap(function) if callable(function) else function    # lru_cache, wraps
        if (inspect.isfunction(function) or inspect.isclass(function)) and function.__module__ == module:
            yield name, function


def _class_problems(path: str, cls: type) -> list[str]:
    doc = inspect.getdoc(cls) if cls.__doc__ else None
    if not doc:
        return [f"{path}: GL08 no docstring"]
    if issubclass(cls, BaseModel):
        return [f"{path}.{name}: no docstring below the field" for name, field in cls.model_fields.items()
                if name in vars(cls).get("__annotations__", {}) and not field.description]
    if dataclasses.is_dataclass(cls):
        sections = ("Parameters", "Attributes")
        documented = _documented_names(doc, sections)
        return [f"{path}: field {field.name!r} not under {' or '.join(sections)}"
                for field in dataclasses.fields(cls) if field.name not in documented and not field.name.startswith("_")
                and field.name in vars(cls).get("__annotations__", {})]
    if "__init__" in vars(cls):
        return _errors(path, cls, CLASS_CODES)
    return []


def _documented_names(doc: str, sections: tuple[str, ...]) -> set[str]:
    parsed = NumpyDocString(doc)
    return {name.strip() for section in sections for entry in parsed[section]
            for name in entry.name.split(",")}


def _errors(path: str, obj: object, codes: frozenset[str]) -> list[str]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")     # numpydoc warns of sections it does not know
        result = numpydoc_validate.validate(numpydoc_validate.get_doc_object(obj))
    return [f"{path}: {code} {message}" for code, message in result["errors"] if code in codes]


def problems(package: str) -> tuple[list[str], int]:
    """The docstring problems of a package's public callables, and how many callables were checked."""
    found: list[str] = []
    checked = 0
    for module_name in _modules(package):
        module = importlib.import_module(module_name)
        for name, value in _public(vars(module), module_name):
            path = f"{module_name}.{name}"
            checked += 1
            if inspect.isclass(value):
                found += _class_problems(path, value)
                for method_name, method in _public(vars(value), module_name):
                    if inspect.isfunction(method):
                        checked += 1
                        found += _errors(f"{path}.{method_name}", method, FUNCTION_CODES)
                for attribute, member in vars(value).items():
                    if isinstance(member, property) and not attribute.startswith("_"):
                        checked += 1
                        if not (member.fget and member.fget.__doc__):
                            found.append(f"{path}.{attribute}: property without a docstring")
            else:
                found += _errors(path, value, FUNCTION_CODES)
    return found, checked


@pytest.mark.parametrize("package", PACKAGES)
def test_public_callables_have_numpydoc_docstrings(package):
    found, checked = problems(package)
    assert checked > 0
    assert not found, f"{len(found)} of {checked} public callables of {package}:\n" + "\n".join(found)


def test_the_check_finds_what_it_is_meant_to(tmp_path, monkeypatch):
    """The check is not blind: a module with an undocumented parameter, a missing Returns section and a
    dataclass field outside the docstring fails it; the same module documented passes."""
    bad = '''
import dataclasses

def area_m2(width_m, height_m):
    """Area of a rectangle.

    Parameters
    ----------
    width_m : float
        Width (m).
    """
    return width_m * height_m

@dataclasses.dataclass
class Box:
    """A box.

    Attributes
    ----------
    depth_m : float
        Depth (m).
    """

    depth_m: float
    mass_kg: float
'''
    good = bad.replace('    """\n    return', '''    height_m : float
        Height (m).

    Returns
    -------
    float
        Area (m^2).
    """
    return''').replace('        Depth (m).\n', '        Depth (m).\n    mass_kg : float\n        Mass (kg).\n')
    package = tmp_path / "docstring_probe"
    package.mkdir()
    (package / "__init__.py").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path))
    (package / "shapes.py").write_text(bad)
    found, checked = problems("docstring_probe")
    assert checked == 2
    assert sorted(line.split(":")[1].split()[0] for line in found) == ["PR01", "RT01", "field"]
    (package / "shapes.py").write_text(good)
    importlib.invalidate_caches()
    importlib.reload(importlib.import_module("docstring_probe.shapes"))
    assert problems("docstring_probe") == ([], 2)
