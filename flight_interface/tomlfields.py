"""TOML configuration at the edge: read a file, validate it into a typed pydantic model, one-line errors.

Every TOML table is declared once, as a :class:`ConfigModel` (pydantic v2): field names, types, units
(in the names and docstrings), ranges and defaults live there and nowhere else; unknown keys are
refused. :func:`parse` validates parsed TOML data into a model and turns pydantic's
``ValidationError`` into a :class:`ConfigError` whose message is one line naming the file, the dotted
field path and what is allowed, e.g.::

    sitedata/cameras/mer_a.toml: geometry.focal_length_m = -0.01 is out of range; allowed: > 0 and <= 10

Configuration is data: the core never parses text, it receives the typed objects built here.
"""
from __future__ import annotations

import stat
import tomllib
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, TypeVar

import annotated_types
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, ValidationInfo
from pydantic.fields import FieldInfo


class ConfigError(ValueError):
    """A configuration value is missing, of the wrong type or out of range (one-line message)."""


class FieldProblem(ValueError):
    """Raised by a validator for a check that involves several fields: names the field at fault.

    The one-line error then points at that field. The message follows the field's dotted path,
    e.g. ``"= 3 must divide ..."``.

    Parameters
    ----------
    field : str
        The field at fault, relative to the model being validated; ``""`` = the value being validated.
    message : str
        What is wrong and what is allowed.
    """

    def __init__(self, field: str, message: str):
        super().__init__(message)
        self.field = field


class ConfigModel(BaseModel):
    """Base of every configuration table.

    Unknown keys refused, no type coercion (TOML types are exact: ``"1"`` is not a number, ``1`` is not a
    boolean), finite numbers only, immutable.
    """

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False,
                              use_attribute_docstrings=True, validate_default=False)


Model = TypeVar("Model", bound=BaseModel)


def _as_tuple(value: Any) -> Any:
    return tuple(value) if isinstance(value, list) else value


def fixed_vector(length: int) -> Any:
    """Annotation of a TOML list of exactly ``length`` finite numbers, held as a tuple of floats.

    Parameters
    ----------
    length : int
        Number of elements.

    Returns
    -------
    Annotated
        ``tuple[float, ...]`` of that length, with a validator that names a wrong length.
    """

    def as_tuple(value: Any) -> Any:
        if isinstance(value, list) and len(value) != length:
            raise FieldProblem("", f"must be a list of {length} numbers; got {value!r}")
        return _as_tuple(value)

    # the tuple's length is a run-time value, which a static checker cannot express
    return Annotated[tuple[(float,) * length], BeforeValidator(as_tuple)]  # type: ignore[misc]


FloatList = Annotated[tuple[float, ...], BeforeValidator(_as_tuple)]
StringList = Annotated[tuple[str, ...], BeforeValidator(_as_tuple)]


def _relative_to_file(value: Any, info: ValidationInfo) -> Any:
    """A path string relative to the directory of the TOML file (validation ``context["base_dir"]``)."""
    if isinstance(value, str):
        path = Path(value)
        return path if path.is_absolute() else Path((info.context or {}).get("base_dir", ".")) / path
    return value


def _existing_file(value: Any, info: ValidationInfo) -> Any:
    path = _relative_to_file(value, info)
    if isinstance(path, Path) and not path.is_file():
        raise FieldProblem("", f"= {str(value)!r}: no such file {path}")
    return path


#: A path in a TOML file, relative to the file's directory (a string in the file, a Path here).
InputPath = Annotated[Path, BeforeValidator(_relative_to_file)]
#: Same, and the file must exist.
ExistingFile = Annotated[Path, BeforeValidator(_existing_file)]


def load_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file; any I/O, encoding or syntax problem is a one-line :class:`ConfigError`.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    dict
        The parsed tables.

    Raises
    ------
    ConfigError
        One line naming the file and the problem.
    """
    path = Path(path)
    try:
        if not stat.S_ISREG(path.stat().st_mode) and not path.is_dir():   # a FIFO would block, /dev/zero never ends
            raise ConfigError(f"{path}: is not a regular file (a FIFO, device or socket); allowed: a TOML file")
        with path.open("rb") as handle:
            return tomllib.load(handle)
    except RecursionError:
        raise ConfigError(f"{path}: arrays or inline tables nested too deeply; allowed: the tables of its schema") from None
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory; allowed: a TOML file") from None
    except PermissionError:
        raise ConfigError(f"{path}: cannot be read (permission denied)") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot be read ({exc.strerror or type(exc).__name__})") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: is not UTF-8 text (byte {exc.start}); allowed: a UTF-8 TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from None


def parse(model: type[Model], data: Any, source: str | Path, prefix: str = "", context: dict | None = None) -> Model:
    """Validate ``data`` (parsed TOML) as ``model``.

    Parameters
    ----------
    model : type of BaseModel
        The model (a :class:`ConfigModel`).
    data : Any
        Parsed TOML (a dict of tables).
    source : str or Path
        The file (or other source) named in errors.
    prefix : str, optional
        Dotted path of ``data`` in its file (e.g. ``"scene"``), prefixed to field paths in errors.
    context : dict or None, optional
        Validation context (e.g. ``base_dir`` for relative paths).

    Returns
    -------
    BaseModel
        The validated ``model`` instance.

    Raises
    ------
    ConfigError
        One line naming the file, the field and the allowed values.
    """
    try:
        return model.model_validate(data, context=context)
    except ValidationError as exc:
        raise translate(exc, model, str(source), prefix) from None


def parse_field(model: type[Model], field: str, value: Any, source: str, label: str) -> Any:
    """Validate one value (e.g. a command-line flag) against ``model``'s declaration of ``field``.

    Parameters
    ----------
    model : type of BaseModel
        The model declaring ``field``; its other fields must have defaults.
    field : str
        The field's name.
    value : Any
        The value to validate.
    source : str
        The source named in errors.
    label : str
        What errors call the value (e.g. ``--workers``) instead of the field's name.

    Returns
    -------
    Any
        The validated value.

    Raises
    ------
    ConfigError
        One line naming the file, the field and the allowed values.
    """
    try:
        return getattr(model.model_validate({field: value}), field)
    except ValidationError as exc:
        error = translate(exc, model, source)
        prefix = f"{source}: {field}"
        text = str(error)
        raise ConfigError(f"{source}: {label}{text[len(prefix):]}" if text.startswith(prefix) else text) from None


def load(model: type[Model], path: str | Path, context: dict | None = None) -> Model:
    """:func:`load_toml` then :func:`parse` the whole file as ``model``.

    Parameters
    ----------
    model : type of BaseModel
        The model of the whole file.
    path : str or Path
        The file.
    context : dict or None, optional
        Validation context (e.g. ``base_dir`` for relative paths).

    Returns
    -------
    BaseModel
        The validated ``model`` instance.

    Raises
    ------
    ConfigError
        One line naming the file, the field and the allowed values.
    """
    return parse(model, load_toml(path), path, context=context)


# --------------------------------------------------------------------------------- error translation
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


__all__ = ["ConfigError", "ConfigModel", "ExistingFile", "Field", "InputPath", "FieldProblem", "FloatList", "StringList", "fixed_vector",
           "describe_range", "load", "load_toml", "parse", "parse_field", "translate"]
