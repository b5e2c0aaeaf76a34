"""Bad-input generator and CLI harness for the fuzz suite (tests/campaign/test_config_fuzz.py).

Bad TOML files are generated from the JSON Schema of each file kind (``campaign schema``), walked together
with a valid example file: for every table an unknown key, a dropped required key and a scalar in place of
the table; for every value a wrong TOML type, values beyond the schema's bounds, non-finite numbers and
strings outside an enum. Every one of them is bad by construction (the schema says so); the harness then
checks the contract: exit status 2, exactly one line on stderr (no traceback), nothing on stdout and
nothing written.
"""
from __future__ import annotations

import contextlib
import copy
import io
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tomli_w

UNKNOWN_KEY = "zz_unknown_key"


# ------------------------------------------------------------------------------------------ harness
@dataclass
class Outcome:
    code: int
    out: str
    err: str


def run_main(main: Callable, argv: list, cwd: Path) -> Outcome:
    """``main(argv)`` in this process, in ``cwd``, with stdout/stderr captured and SystemExit caught."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), contextlib.chdir(cwd):
        try:
            code = main([str(item) for item in argv])
        except SystemExit as exc:
            if isinstance(exc.code, str):
                print(exc.code, file=err)
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    return Outcome(code, out.getvalue(), err.getvalue())


def snapshot(root: Path) -> dict:
    """Every path under ``root`` with size and modification time: "nothing written" compares two."""
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns) if p.is_file() and not p.is_symlink()
            else p.is_dir() for p in sorted(root.rglob("*"))}


def refusal_problems(outcome: Outcome, before: dict, after: dict) -> list[str]:
    """What breaks the bad-input contract (empty when the input was refused properly)."""
    problems = []
    if outcome.code != 2:
        problems.append(f"exit status {outcome.code}")
    lines = [line for line in outcome.err.splitlines() if line.strip()]
    if len(lines) != 1 or "Traceback" in outcome.err:
        problems.append(f"{len(lines)} stderr lines: {outcome.err[-600:]!r}")
    if outcome.out:
        problems.append(f"stdout: {outcome.out[:200]!r}")
    if before != after:
        changed = sorted(set(before.items()) ^ set(after.items()))
        problems.append(f"written: {changed[:5]}")
    return problems


# ------------------------------------------------------------------------------------ schema mutations
def _resolve(schema: dict, node: dict, value: Any = None) -> dict:
    """Follow $ref, drop the ``null`` branch of optional fields, pick the discriminated member."""
    while True:
        if "$ref" in node:
            node = schema["$defs"][node["$ref"].rsplit("/", 1)[-1]]
        elif "anyOf" in node and sum(branch.get("type") != "null" for branch in node["anyOf"]) == 1:
            node = next(branch for branch in node["anyOf"] if branch.get("type") != "null")
        elif "oneOf" in node and isinstance(value, dict):
            members = [_resolve(schema, member) for member in node["oneOf"]]
            tagged = [m for m in members if m.get("properties", {}).get("kind", {}).get("const") == value.get("kind")]
            node = tagged[0] if tagged else members[0]
        else:
            return node


def _child(schema: dict, node: dict, key: Any) -> dict | None:
    if "properties" in node or node.get("type") == "object":
        if key in node.get("properties", {}):
            return node["properties"][key]
        extra = node.get("additionalProperties")
        return extra if isinstance(extra, dict) else None
    if node.get("type") == "array":
        if "prefixItems" in node:
            return node["prefixItems"][key] if key < len(node["prefixItems"]) else None
        return node.get("items")
    return None


def _walk(schema: dict, node: dict, value: Any, path: tuple) -> Iterator[tuple[tuple, dict, Any]]:
    node = _resolve(schema, node, value)
    yield path, node, value
    if isinstance(value, dict):
        for key, item in value.items():
            child = _child(schema, node, key)
            if child is not None:
                yield from _walk(schema, child, item, path + (key,))
    elif isinstance(value, list) and value and isinstance(value[0], dict):
        for index, item in enumerate(value):
            child = _child(schema, node, index)
            if child is not None:
                yield from _walk(schema, child, item, path + (index,))


def _bad_values(node: dict) -> list[tuple[str, Any]]:
    """Values the schema node forbids: (what, value)."""
    kind = node.get("type")
    if "enum" in node or "const" in node:
        return [("not allowed", "zz-not-a-choice"), ("wrong type", 7)]
    if kind in ("number", "integer"):
        bad = [("wrong type", "12"), ("wrong type", True)]
        if kind == "integer":
            bad.append(("not an integer", 1.5))
        else:
            bad += [("not finite", math.nan), ("not finite", math.inf)]
        for key, sign in (("minimum", -1), ("exclusiveMinimum", 0), ("maximum", 1), ("exclusiveMaximum", 0)):
            if key in node:
                bound = node[key]
                value = bound + sign * (abs(bound) + 1) if sign else bound
                if kind == "integer":
                    value = int(math.floor(value) if sign < 0 else math.ceil(value))
                bad.append((f"beyond {key}", value))
        return bad
    if kind == "boolean":
        return [("wrong type", "yes"), ("wrong type", 1)]
    if kind == "string":
        return [("wrong type", 12), ("wrong type", [1.5])]
    if kind == "array":
        if "prefixItems" in node:
            size = len(node["prefixItems"])
            return [("wrong length", [0.5] * (size + 1)), ("wrong item type", ["x"] * size), ("wrong type", 0.5)]
        return [("wrong type", 0.5), ("wrong item type", [{"x": 1}])]
    return []


def with_value(data: dict, path: tuple, value: Any) -> dict:
    """A deep copy of ``data`` with the item at ``path`` (keys and indices) set to ``value``."""
    data = copy.deepcopy(data)
    node = data
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return data


def _drop(data: dict, path: tuple) -> dict:
    data = copy.deepcopy(data)
    node = data
    for key in path[:-1]:
        node = node[key]
    del node[path[-1]]
    return data


def schema_mutations(schema: dict, data: dict, skip: tuple[tuple, ...] = ()) -> list[tuple[str, dict]]:
    """Every bad variant of ``data`` the schema defines: (description, data)."""
    variants = []
    for path, node, value in _walk(schema, schema, data, ()):
        if any(path[:len(prefix)] == prefix for prefix in skip):
            continue
        name = ".".join(str(part) for part in path) or "<root>"
        if isinstance(value, dict):
            if node.get("additionalProperties") is False:
                variants.append((f"{name}: unknown key", with_value(data, path + (UNKNOWN_KEY,), 1.0) if path
                                 else {**data, UNKNOWN_KEY: 1.0}))
            for key in node.get("required", []):
                if key in value:
                    variants.append((f"{name + '.' if path else ''}{key}: dropped", _drop(data, path + (key,))))
            if path:
                variants.append((f"{name}: a number instead of a table", with_value(data, path, 3.5)))
            continue
        if isinstance(value, list) and value and isinstance(value[0], dict):
            variants.append((f"{name}: empty array of tables", with_value(data, path, [])))
            continue
        for what, bad in _bad_values(node):
            variants.append((f"{name} = {bad!r}: {what}", with_value(data, path, bad)))
    return variants


def toml_text(data: dict) -> str:
    return tomli_w.dumps(data)
