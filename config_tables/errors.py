"""The one-line configuration errors, cheap to import (no pydantic).

Every command line can catch them before it loads anything else.

A :class:`ConfigError` is raised for any bad input at the edge (a TOML file, a command-line value, a path); its
message is one line naming the file, the dotted field path and what is allowed, e.g.::

    sitedata/cameras/mer_a.toml: geometry.focal_length_m = -0.01 is out of range; allowed: > 0 and <= 10

A :class:`FieldProblem` is raised inside a table's validator to name the field at fault
(:mod:`config_tables.messages` turns it into the one-line message).
"""
from __future__ import annotations


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
