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


# ------------------------------------------------------------------------------------------ bad paths
def bad_input_paths(root: Path) -> list[tuple[str, Path | str]]:
    """Paths that are no usable input file, generated under ``root`` (plus system devices): (class, path).

    Classes: empty, a name over 255 bytes (256, 300), a path over 4095 bytes (short names), a directory, a
    FIFO, character devices, a socket, a dangling symbolic link, a symbolic-link loop, a name below a file."""
    import os
    import socket

    root.mkdir(parents=True, exist_ok=True)
    regular = root / "regular.toml"
    regular.write_text("")
    (root / "a-directory.toml").mkdir(exist_ok=True)
    fifo = root / "fifo.toml"
    if not fifo.exists():
        os.mkfifo(fifo)
    sock = root / "sock.toml"
    if not sock.exists():
        server = socket.socket(socket.AF_UNIX)
        server.bind(str(sock))
        server.close()
    dangling, loop = root / "dangling.toml", root / "loop.toml"
    if not dangling.is_symlink():
        dangling.symlink_to(root / "nowhere" / "x.toml")
    if not loop.is_symlink():
        loop.symlink_to(loop)
    return [("empty", ""), ("name of 256 bytes", root / ("n" * 252 + ".toml")),
            ("name of 300 bytes", root / ("é" * 148 + ".toml")),      # 296 bytes of UTF-8 + 5
            ("path over 4095 bytes", root.joinpath(*(["d" * 200] * 21), "x.toml")),
            ("directory", root / "a-directory.toml"), ("FIFO", fifo), ("device /dev/null", "/dev/null"),
            ("device /dev/zero", "/dev/zero"), ("socket", sock), ("dangling symlink", dangling),
            ("symlink loop", loop), ("below a file", regular / "x.toml")]


def bad_output_dirs(root: Path) -> list[tuple[str, Path | str]]:
    """Paths where no output directory can be made or written, generated under ``root``: (class, path).

    Classes: empty, names too long, a regular file, a device, a FIFO, a socket, a dangling symbolic link, a
    name below a file, a directory under /proc/sys (read-only even for root)."""
    inputs = dict(bad_input_paths(root))
    return [("empty", ""), ("name of 300 bytes", inputs["name of 300 bytes"]),
            ("path over 4095 bytes", inputs["path over 4095 bytes"]), ("regular file", root / "regular.toml"),
            ("device /dev/null", "/dev/null"), ("FIFO", inputs["FIFO"]), ("socket", inputs["socket"]),
            ("dangling symlink", inputs["dangling symlink"]), ("below a file", root / "regular.toml" / "out"),
            ("under /proc/sys", "/proc/sys/kernel/campaign-out")]


def corrupt_file_variants(path: Path) -> list[tuple[str, Callable[[], None]]]:
    """Ways to damage an existing file in place: (class, damage()). Empty, truncated to half, random bytes,
    JSON of the wrong shape, a directory, a FIFO or a dangling symbolic link in its place."""
    import os
    import random
    import shutil

    original = path.read_bytes()

    def replace_with(make: Callable[[], None]) -> Callable[[], None]:
        def damage() -> None:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            elif path.exists() or path.is_symlink():
                path.unlink()
            make()
        return damage

    noise = bytes(random.Random(len(original)).getrandbits(8) for _ in range(512))
    return [("empty", replace_with(lambda: path.write_bytes(b""))),
            ("truncated", replace_with(lambda: path.write_bytes(original[:len(original) // 2]))),
            ("random bytes", replace_with(lambda: path.write_bytes(noise))),
            ("JSON list", replace_with(lambda: path.write_text("[1, 2, 3]"))),
            ("JSON null", replace_with(lambda: path.write_text("null"))),
            ("directory", replace_with(lambda: path.mkdir())),
            ("FIFO", replace_with(lambda: os.mkfifo(path))),
            ("dangling symlink", replace_with(lambda: path.symlink_to(path.parent / "nowhere")))]


def deep_toml_texts(depths: tuple[int, ...] = (200, 1000, 5000)) -> list[tuple[str, str]]:
    """TOML documents nested beyond any schema: arrays, inline tables and both mixed, at each depth
    (class, text); the value sits under ``[site]`` so the file is otherwise a plausible campaign file."""
    texts = []
    for depth in depths:
        texts.append((f"arrays x{depth}", "[site]\nname = " + "[" * depth + "]" * depth + "\n"))
        texts.append((f"inline tables x{depth}", "[site]\nname = " + "{a = " * depth + "1" + "}" * depth + "\n"))
        texts.append((f"mixed x{depth}", "[site]\nname = " + "[{a = " * (depth // 2) + "1" + "}]" * (depth // 2) + "\n"))
        texts.append((f"dotted keys x{depth}", "[site]\n" + ".".join(["k"] * depth) + " = 1\n"))
    return texts


def no_traceback_problems(outcome: Outcome, allowed_codes: tuple[int, ...] = (1, 2)) -> list[str]:
    """What breaks "no traceback, one line, documented exit code" for a command that may legitimately list
    things on stdout (verify) or exit 1 (a store with bad files)."""
    problems = []
    if outcome.code not in allowed_codes:
        problems.append(f"exit status {outcome.code}")
    lines = [line for line in outcome.err.splitlines() if line.strip()]
    if "Traceback" in outcome.err or len(lines) > 1:
        problems.append(f"stderr: {outcome.err[-600:]!r}")
    return problems
