"""A pydantic ``ValidationError`` as one line: the file, the dotted field path, the problem and what is allowed.

:func:`translate` walks the error's location through the model's declaration (nested tables, lists, tagged
unions) to find the field's bounds, literal values or known keys, and words the first problem, e.g.::

    sitedata/cameras/mer_a.toml: geometry.focal_length_m = -0.01 is out of range; allowed: > 0 and <= 10
"""
from __future__ import annotations

import types
import typing
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import annotated_types
from pydantic import BaseModel, ValidationError
from pydantic.fields import FieldInfo

from config_tables.errors import ConfigError, FieldProblem


def translate(exc: ValidationError, model: type[BaseModel], source: str, prefix: str = "") -> ConfigError:
    """The first problem of a pydantic ``ValidationError`` as a one-line :class:`ConfigError`.

    Parameters
    ----------
    exc : ValidationError
        The error of validating ``model``.
    model : type of BaseModel
        The model validated.
    source : str
        The file (or other source) named in the message.
    prefix : str, optional
        Dotted path of the validated data in its file.

    Returns
    -------
    ConfigError
        The error to raise: source, dotted field path, problem and what is allowed.
    """
    errors = exc.errors(include_url=False)
    error = next((e for e in errors if e["type"] == "extra_forbidden"), errors[0])   # a typo before "missing"
    where = _walk(model, error["loc"], prefix)
    return ConfigError(f"{source}: {_describe(error, where)}")


class _Where:
    """What the walk along an error location found.

    The dotted path, the field's annotation metadata, the innermost model and the annotation at the end.

    Parameters
    ----------
    path : str
        The dotted path so far.
    """

    def __init__(self, path: str):
        self.path = path
        self.metadata: list = []
        self.container: type[BaseModel] | None = None
        self.annotation: Any = None


def _unwrap(annotation: Any) -> tuple[Any, list]:
    metadata = []
    while True:
        origin = typing.get_origin(annotation)
        if origin is Annotated:
            annotation, *extra = typing.get_args(annotation)
            for item in extra:
                metadata.extend(item.metadata if isinstance(item, FieldInfo) else [item])
        elif origin in (typing.Union, types.UnionType):
            members = [a for a in typing.get_args(annotation) if a is not type(None)]
            if len(members) != 1:
                return annotation, metadata
            annotation = members[0]
        else:
            return annotation, metadata


def _models_of(annotation: Any) -> list[type[BaseModel]]:
    annotation, _ = _unwrap(annotation)
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return [m for a in typing.get_args(annotation) for m in _models_of(a)]
    return []


def _walk(model: type[BaseModel], loc: tuple, prefix: str) -> _Where:
    where = _Where(prefix)
    current: Any = model
    for item in loc:
        current, metadata = _unwrap(current)
        origin = typing.get_origin(current)
        if isinstance(item, int) and origin in (list, tuple):
            args = typing.get_args(current)
            where.path += f"[{item}]"
            current = args[0] if origin is list or (len(args) == 2 and args[1] is Ellipsis) else args[item]
            where.metadata = []
            continue
        if origin is dict:
            where.path = f"{where.path}.{item}" if where.path else str(item)
            current = typing.get_args(current)[1]
            where.metadata = []
            continue
        models = _models_of(current)
        if len(models) > 1 and isinstance(item, str):          # a tagged union: the tag names the member
            tagged = [m for m in models if _tag_of(m) == item]
            if tagged:
                current = tagged[0]
                continue
        if models:
            container = next((m for m in models if item in m.model_fields), models[0])
            where.container = container
            where.path = f"{where.path}.{item}" if where.path else str(item)
            if item in container.model_fields:
                info = container.model_fields[item]
                current, where.metadata = info.annotation, list(info.metadata)
            else:
                current, where.metadata = None, []
            continue
        where.path = f"{where.path}.{item}" if where.path else str(item)
        current = None
    where.annotation, extra = _unwrap(current) if current is not None else (None, [])
    where.metadata = where.metadata + extra
    if isinstance(where.annotation, type) and issubclass(where.annotation, BaseModel):
        where.container = where.annotation
    return where


def _tag_of(model: type[BaseModel]) -> str | None:
    for info in model.model_fields.values():
        annotation, _ = _unwrap(info.annotation)
        if typing.get_origin(annotation) is Literal and len(typing.get_args(annotation)) == 1:
            return typing.get_args(annotation)[0]
    return None


def describe_range(metadata: list) -> str:
    """'>= 0 and <= 30' from annotated-types bounds (``Field(ge=..., le=...)``).

    Parameters
    ----------
    metadata : list
        A field's annotation metadata.

    Returns
    -------
    str
        The bounds joined by ``and``, lower first; ``"any finite number"`` without bounds.
    """
    parts = []
    for item in metadata:
        for kind, symbol in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            bound = getattr(item, kind, None)
            if bound is not None and isinstance(item, (annotated_types.Gt, annotated_types.Ge, annotated_types.Lt,
                                                       annotated_types.Le, annotated_types.Interval)):
                parts.append((0 if symbol.startswith(">") else 1, f"{symbol} {_number(bound)}"))
    return " and ".join(text for _, text in sorted(parts)) or "any finite number"


def _number(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return f"{value:g}"
    return repr(value)


def _got(value: Any) -> str:
    text = repr(value)
    if len(text) > 80:
        text = text[:77] + "..."
    return f"{type(value).__name__} {text}"


_EXPECTED = {"int_type": "an integer", "int_from_float": "an integer", "float_type": "a number",
             "bool_type": "true or false", "string_type": "a string", "model_type": "a table",
             "model_attributes_type": "a table", "dict_type": "a table", "list_type": "a list",
             "tuple_type": "a list", "path_type": "a path (string)"}


def _describe(error: Mapping[str, Any], where: _Where) -> str:
    kind, value, ctx = error["type"], error.get("input"), error.get("ctx") or {}
    path = where.path or "<root>"
    if kind == "missing":
        return f"{path} is missing"
    if kind == "extra_forbidden":
        allowed = ", ".join(where.container.model_fields) if where.container else "none"
        return f"{path} is not a known field; allowed: {allowed}"
    if kind == "literal_error":
        allowed = ctx.get("expected", "")
        if typing.get_origin(where.annotation) is Literal:
            allowed = ", ".join(str(a) for a in typing.get_args(where.annotation))
        return f"{path} = {value!r} is not allowed; allowed: {allowed}"
    if kind in ("union_tag_invalid", "union_tag_not_found"):
        field = ctx.get("discriminator", "kind").strip("'")
        allowed = ", ".join(t.strip("'") for t in str(ctx.get("expected_tags", "")).split(", "))
        if kind == "union_tag_not_found":
            return f"{path}.{field} is missing; allowed: {allowed}"
        return f"{path}.{field} = {ctx.get('tag')!r} is not allowed; allowed: {allowed}"
    if kind in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
        bounds = where.metadata or [annotated_types.Interval(**{k: v for k, v in ctx.items()})]
        return f"{path} = {_number(value)} is out of range; allowed: {describe_range(bounds)}"
    if kind == "finite_number":
        return f"{path} = {value} is not finite; allowed: {describe_range(where.metadata)}"
    if kind in ("too_short", "too_long"):
        if isinstance(value, (list, tuple)) and typing.get_origin(where.annotation) is tuple \
                and Ellipsis not in typing.get_args(where.annotation):
            return f"{path} must be a list of {len(typing.get_args(where.annotation))} numbers; got {list(value)!r}"
        bound = ctx.get("min_length") if kind == "too_short" else ctx.get("max_length")
        return (f"{path} has {ctx.get('actual_length')} entries; allowed: "
                f"{'at least' if kind == 'too_short' else 'at most'} {bound}")
    if kind in _EXPECTED:
        expected = _EXPECTED[kind]
        if kind == "tuple_type" and typing.get_origin(where.annotation) is tuple:
            args = typing.get_args(where.annotation)
            expected = "a list of numbers" if Ellipsis in args else f"a list of {len(args)} numbers"
        return f"{path} must be {expected}; got {_got(value)}"
    if kind in ("value_error", "assertion_error"):
        problem = ctx.get("error")
        if isinstance(problem, FieldProblem):
            joiner = "" if problem.field.startswith("[") else "."
            field = joiner.join(part for part in (where.path, problem.field) if part) or "<root>"
            message = str(problem)
            return f"{field}{'' if message.startswith((':', ',')) else ' '}{message}"
        message = str(problem) if problem is not None else error["msg"]
        return f"{path}: {message}" if where.path else message
    return f"{path}: {error['msg']}"

