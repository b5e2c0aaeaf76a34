"""Temporary: the tests' old import path of :mod:`config_tables.command_line` (removed with them)."""
from config_tables.command_line import USAGE_ERROR, OneLineParser

__all__ = ["USAGE_ERROR", "OneLineParser"]
