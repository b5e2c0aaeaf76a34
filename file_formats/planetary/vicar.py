"""VICAR image reader and MSSS DDD reader (raw MOC frames).

VICAR: the label starts ``LBLSIZE=n`` and is ``n`` bytes of ``KEY=value`` pairs (integers, reals,
'quoted strings' with '' escapes, parenthesised lists). System keywords used: ``FORMAT`` (BYTE,
HALF/WORD, FULL/LONG, REAL, DOUB), ``ORG`` (BSQ/BIL/BIP), ``NL``/``NS``/``NB``, ``NBB`` (binary
prefix bytes per record), ``NLB`` (binary header records), ``RECSIZE``, ``INTFMT`` (HIGH = MSB,
LOW = LSB), ``REALFMT`` (IEEE = MSB, RIEEE = LSB; VAX refused). Only the system label (before the
first ``PROPERTY``/``TASK`` keyword) defines the layout.

DDD (MSSS raw-frame format): a 1024-byte header of big-endian 32-bit words -- magic 1659, lines,
bytes per line, bits per pixel, a type word, the data offset -- then an ASCII note, then the data
(8-bit unsigned, 16-bit unsigned or 32-bit float, big-endian, one band).
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from file_formats.planetary.image import OrbitalImage, fail, file_size
from file_formats.planetary.layout import RasterLayout, check_dimensions, decode_band

_FORMATS = {"BYTE": ("u", 1), "HALF": ("i", 2), "WORD": ("i", 2), "FULL": ("i", 4), "LONG": ("i", 4),
            "REAL": ("f", 4), "DOUB": ("f", 8)}
_VICAR_VALUE = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)=\s*('(?:[^']|'')*'|\([^)]*\)|[^\s]+)")
DDD_MAGIC = 1659
DDD_HEADER_BYTES = 1024


def looks_like_vicar(head: bytes) -> bool:
    return head.startswith(b"LBLSIZE=")


def looks_like_ddd(head: bytes) -> bool:
    return len(head) >= 4 and int.from_bytes(head[:4], "big") == DDD_MAGIC


def parse_vicar_label(path: Path) -> tuple[dict, int]:
    """The VICAR system label as a dict (first occurrence of each keyword wins) and LBLSIZE."""
    with path.open("rb") as handle:
        head = handle.read(64)
    match = re.match(rb"LBLSIZE=\s*(\d+)", head)
    if match is None:
        raise fail(path, "not a VICAR file: it does not start with LBLSIZE=<integer>")
    label_size = int(match.group(1))
    if label_size <= 0 or label_size > file_size(path):
        raise fail(path, f"LBLSIZE = {label_size} is not a valid label size (file has {file_size(path)} bytes)")
    with path.open("rb") as handle:
        raw = handle.read(label_size)
    text = raw.split(b"\x00", 1)[0].decode("latin-1")
    label: dict = {}
    position = 0
    while True:
        item = _VICAR_VALUE.match(text, position)
        if item is None:
            break
        key, value = item.group(1).upper(), item.group(2)
        position = item.end()
        if key in ("PROPERTY", "TASK") and label:
            label.setdefault("_HISTORY", []).append((key, _vicar_value(value)))
            continue
        if "_HISTORY" in label:
            label["_HISTORY"].append((key, _vicar_value(value)))
        else:
            label.setdefault(key, _vicar_value(value))
    if text[position:].strip():
        raise fail(path, f"VICAR label is not valid near byte {position}: {text[position:position + 24]!r}")
    return label, label_size


def _vicar_value(token: str):
    if token.startswith("'"):
        return token[1:-1].replace("''", "'")
    if token.startswith("("):
        return [_vicar_value(part.strip()) for part in re.findall(r"'(?:[^']|'')*'|[^,\s]+", token[1:-1])]
    for cast in (int, float):
        try:
            return cast(token)
        except ValueError:
            pass
    return token


def _vicar_int(path: Path, label: dict, key: str, default=None) -> int:
    value = label.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise fail(path, f"VICAR keyword {key} = {value!r} is missing or not an integer")
    return value


def read_vicar(path: str | Path, band_index: int = 0) -> OrbitalImage:
    """Read one band of a VICAR image.

    Parameters
    ----------
    path : path-like
    band_index : int
        0-based band.
    """
    path = Path(path)
    label, label_size = parse_vicar_label(path)
    format_name = str(label.get("FORMAT", "<missing>")).upper()
    if format_name not in _FORMATS:
        raise fail(path, f"VICAR FORMAT = {format_name!r} is not supported; allowed: {', '.join(_FORMATS)}")
    kind, size = _FORMATS[format_name]
    if kind == "f":
        real_format = str(label.get("REALFMT", "IEEE")).upper()
        orders = {"IEEE": ">", "RIEEE": "<"}
        if real_format not in orders:
            raise fail(path, f"VICAR REALFMT = {real_format} is not supported; allowed: IEEE, RIEEE")
        order = orders[real_format]
    else:
        int_format = str(label.get("INTFMT", "HIGH")).upper()
        orders = {"HIGH": ">", "LOW": "<"}
        if int_format not in orders:
            raise fail(path, f"VICAR INTFMT = {int_format} is not supported; allowed: HIGH, LOW")
        order = orders[int_format]
    dtype = np.dtype(f"{'|' if size == 1 else order}{kind}{size}")
    lines, samples = _vicar_int(path, label, "NL"), _vicar_int(path, label, "NS")
    bands = _vicar_int(path, label, "NB", 1)
    check_dimensions(path, lines, samples, bands, ("NL", "NS", "NB"))
    organisation = str(label.get("ORG", "BSQ")).upper()
    if organisation not in ("BSQ", "BIL", "BIP"):
        raise fail(path, f"VICAR ORG = {organisation} is not supported; allowed: BSQ, BIL, BIP")
    prefix = _vicar_int(path, label, "NBB", 0)
    header_records = _vicar_int(path, label, "NLB", 0)
    layout = RasterLayout(lines, samples, bands, dtype, organisation, prefix_bytes=prefix)
    record_size = _vicar_int(path, label, "RECSIZE", layout.line_bytes)
    if record_size != layout.line_bytes:
        raise fail(path, f"VICAR RECSIZE = {record_size} disagrees with NBB + samples x {format_name} "
                         f"({layout.line_bytes} bytes)")
    offset = label_size + header_records * record_size
    pixels, valid = decode_band(path, offset, layout, band_index, f"VICAR {format_name} image")
    return OrbitalImage(pixels=pixels, valid=valid, source=path, file_format="VICAR", label=label,
                        band_index=band_index, band_count=bands)


def read_ddd(path: str | Path) -> OrbitalImage:
    """Read an MSSS DDD raw frame (one band)."""
    path = Path(path)
    size = file_size(path)
    if size < DDD_HEADER_BYTES:
        raise fail(path, f"truncated DDD file: {size} bytes is shorter than the {DDD_HEADER_BYTES}-byte header")
    with path.open("rb") as handle:
        header = handle.read(DDD_HEADER_BYTES)
    words = np.frombuffer(header[:24], dtype=">i4").astype(int)
    magic, lines, line_bytes, bits, type_word, data_offset = words
    if magic != DDD_MAGIC:
        raise fail(path, f"not a DDD file: magic number {magic} (expected {DDD_MAGIC})")
    if (type_word & 0xFFFFF000) == 0x567B0000 and type_word != 0x567B0108:
        raise fail(path, f"DDD type word 0x{type_word:08X} (new-format typed data) is not supported; "
                         f"allowed: 8-bit (0x567B0108) or the old header with 8/16/32 bits")
    dtypes: dict[int, np.dtype] = {8: np.dtype("u1"), 16: np.dtype(">u2"), 32: np.dtype(">f4")}
    if bits not in dtypes:
        raise fail(path, f"DDD bits-per-pixel word = {bits} is not supported; allowed: 8, 16, 32")
    dtype = dtypes[bits]
    if line_bytes % dtype.itemsize:
        raise fail(path, f"DDD bytes-per-line {line_bytes} is not a multiple of {dtype.itemsize} ({bits}-bit pixels)")
    samples = line_bytes // dtype.itemsize
    check_dimensions(path, int(lines), int(samples), 1, ("DDD lines word", "DDD bytes-per-line word", "bands"))
    offset = max(int(data_offset), DDD_HEADER_BYTES) if (type_word & 0xFFFFF000) == 0x567B0000 else DDD_HEADER_BYTES
    note = header[24:].split(b"\x00", 1)[0].decode("latin-1")
    stated = re.search(r"cross (\d+) down (\d+)", note)
    if stated is not None and (int(stated.group(1)), int(stated.group(2))) != (samples, lines):
        raise fail(path, f"DDD header words ({lines} lines x {samples} samples) disagree with its note "
                         f"'cross {stated.group(1)} down {stated.group(2)}'")
    layout = RasterLayout(int(lines), int(samples), 1, dtype)
    pixels, valid = decode_band(path, offset, layout, 0, f"DDD {bits}-bit image")
    label = {"magic": int(magic), "lines": int(lines), "bytes_per_line": int(line_bytes), "bits": int(bits),
             "data_offset": offset, "note": note}
    return OrbitalImage(pixels=pixels, valid=valid, source=path, file_format="DDD", label=label)
