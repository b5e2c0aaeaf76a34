"""TOML configuration at the edge: the typed tables every configuration file is validated into.

Every TOML table is declared once, as a :class:`ConfigModel` (pydantic v2): field names, types, units
(in the names and docstrings), ranges and defaults live there and nowhere else; unknown keys are
refused. :func:`parse` validates parsed TOML data into a model and turns pydantic's
``ValidationError`` into a one-line :class:`~config_tables.errors.ConfigError` naming the file, the dotted
field path and what is allowed (:mod:`config_tables.messages`).

Configuration is data: the core never parses text, it receives the typed objects built here.
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError, ValidationInfo

from config_tables.errors import ConfigError, FieldProblem
from config_tables.messages import translate
from config_tables.toml_file import load_toml


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



__all__ = ["ConfigModel", "ExistingFile", "Field", "FloatList", "InputPath", "StringList", "fixed_vector", "load",
           "parse", "parse_field"]
