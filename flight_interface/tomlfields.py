"""Temporary: the tests' old import path of :mod:`config_tables` (removed when the tests import it directly)."""
from config_tables.errors import ConfigError, FieldProblem
from config_tables.messages import describe_range, translate
from config_tables.models import (
                                  ConfigModel,
                                  ExistingFile,
                                  Field,
                                  FloatList,
                                  InputPath,
                                  StringList,
                                  fixed_vector,
                                  load,
                                  parse,
                                  parse_field,
)
from config_tables.toml_file import load_toml

__all__ = ["ConfigError", "ConfigModel", "ExistingFile", "Field", "FieldProblem", "FloatList", "InputPath", "StringList",
           "describe_range", "fixed_vector", "load", "load_toml", "parse", "parse_field", "translate"]
