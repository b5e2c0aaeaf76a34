"""Parquet bytes held in memory (a case file or index segment read once, checked against its sha256, then
parsed) are parsed on the calling thread, so that no reference to the Python-owned bytes is left on an Arrow
pool thread. A pool thread that drops the last one while the interpreter shuts down cannot take the GIL: the
process ends in ``std::terminate`` (exit -6) after the command's output was written
(:func:`campaign.store.case_files.parquet_file_of_bytes`)."""
from __future__ import annotations

import ast
import sys
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from campaign.store.case_files import parquet_file_of_bytes, table_bytes

REPO = Path(__file__).resolve().parents[3]
PACKAGES = ("campaign", "simulator", "dimes_velocity", "estimators", "file_formats", "flight_interface", "config_tables",
            "sitedata")
READS = 300


def _segment_like_bytes() -> bytes:
    rows = 64
    return table_bytes(pa.table({"batch": pa.array([f"00/batch-{index:06d}-1.parquet" for index in range(rows)]),
                                 "case_id": pa.array(range(rows), pa.int64()),
                                 "failed_estimators": pa.array([["dimes"] if index % 7 == 0 else [] for index in range(rows)])}))


def _reads_leaving_a_reference(read) -> int:
    """How many of READS reads of the same bytes return while something else still holds them (the bytes'
    reference count above what it was before the read, the moment the read and its table are gone)."""
    data = _segment_like_bytes()
    before = sys.getrefcount(data)
    left = 0
    for _ in range(READS):
        table = read(data)
        assert table.num_rows == 64
        del table
        left += sys.getrefcount(data) != before
        while sys.getrefcount(data) != before:       # let the pool let go before the next read
            pass
    return left


def test_the_store_s_read_of_bytes_leaves_no_reference_behind():
    assert _reads_leaving_a_reference(lambda data: parquet_file_of_bytes(data, read_dictionary=["batch"])
                                      .read(use_threads=False)) == 0


def test_a_threaded_read_of_the_same_bytes_does_leave_references_here():
    """The condition the test above watches for exists with this pyarrow: Arrow's threaded read of a buffer
    returns while a pool thread still holds the bytes (46 of 200 ``read_table`` calls on 2026-11-27)."""
    assert _reads_leaving_a_reference(lambda data: pq.read_table(pa.BufferReader(data))) > 0


def _functions(tree: ast.AST):
    return [node for node in ast.walk(tree) if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))]


def _calls(node: ast.AST, name: str) -> list[ast.Call]:
    return [call for call in ast.walk(node) if isinstance(call, ast.Call)
            and (getattr(call.func, "id", None) == name or getattr(call.func, "attr", None) == name)]


def test_the_packages_parse_bytes_only_through_the_calling_thread_reader():
    """No module hands Arrow a Python-owned buffer but the helper, and every function that opens bytes with it
    reads them with ``use_threads=False``."""
    wrong = []
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            tree = ast.parse(path.read_text(), str(path))
            where = path.relative_to(REPO)
            for function in _functions(tree):
                if function.name != "parquet_file_of_bytes":
                    wrong += [f"{where}:{call.lineno}: {ast.unparse(call)[:80]}"
                              for call in _calls(function, "BufferReader") + _calls(function, "py_buffer")]
                if _calls(function, "parquet_file_of_bytes"):
                    wrong += [f"{where}:{call.lineno}: {ast.unparse(call)[:80]}" for call in _calls(function, "read")
                              if not any(keyword.arg == "use_threads" and isinstance(keyword.value, ast.Constant)
                                         and keyword.value.value is False for keyword in call.keywords)]
    assert wrong == []
    assert any(_calls(function, "parquet_file_of_bytes")
               for function in _functions(ast.parse((REPO / "campaign/store/case_index.py").read_text())))
