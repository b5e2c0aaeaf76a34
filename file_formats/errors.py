"""Errors of the file-format readers: one-line messages that name the file and the field."""
from __future__ import annotations


class InputFileError(ValueError):
    """An input file cannot be used; the one-line message names the file and the field."""
