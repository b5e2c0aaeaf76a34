"""The store's one-line error, importable without the store's Parquet stack (the command line catches it)."""
from __future__ import annotations


class StoreError(RuntimeError):
    """The output directory holds another campaign (or is unusable); one-line message."""
