"""Small planetary image files written by hand for the reader tests: a PDS3 file with an attached label, an
ISIS3 cube (tiled or band-sequential) and a VICAR file, each with its label text and bytes laid out explicitly
(tests/file_formats/, tests/dimes_velocity/test_dimes_cli.py)."""
from __future__ import annotations

import numpy as np


def write_pds3(path, lines, samples, sample_type, bits, data: bytes, extra_object="", extra_top="",
               record_bytes=512):
    """A PDS3 file with an attached label padded to whole records and ^IMAGE as a record number."""
    def label(label_records):
        return (f"PDS_VERSION_ID = PDS3\r\nRECORD_TYPE = FIXED_LENGTH\r\nRECORD_BYTES = {record_bytes}\r\n"
                f"LABEL_RECORDS = {label_records}\r\n^IMAGE = {label_records + 1}\r\n{extra_top}"
                f"OBJECT = IMAGE\r\n  LINES = {lines}\r\n  LINE_SAMPLES = {samples}\r\n"
                f"  SAMPLE_TYPE = {sample_type}\r\n  SAMPLE_BITS = {bits}\r\n{extra_object}"
                f"END_OBJECT = IMAGE\r\nEND\r\n")
    records = 1
    while len(label(records)) > records * record_bytes:
        records += 1
    text = label(records).encode("ascii")
    path.write_bytes(text + b" " * (records * record_bytes - len(text)) + data)
    return path


def write_isis(path, bands: np.ndarray, type_name, byte_order, core_format="Tile", tile=(4, 4), base=0.0,
               multiplier=1.0, extra_groups=""):
    """An ISIS3 cube: label padded to 4096 bytes, then the core written tile by tile with plain loops."""
    n_bands, lines, samples = bands.shape
    dtype = np.dtype({"UnsignedByte": "u1", "SignedWord": "i2", "UnsignedWord": "u2", "Real": "f4"}[type_name])
    dtype = dtype.newbyteorder("<" if byte_order == "Lsb" else ">")
    tile_lines, tile_samples = tile
    label = (f"Object = IsisCube\n  Object = Core\n    StartByte   = 4097\n    Format      = {core_format}\n"
             f"    TileSamples = {tile_samples}\n    TileLines   = {tile_lines}\n    Group = Dimensions\n"
             f"      Samples = {samples}\n      Lines   = {lines}\n      Bands   = {n_bands}\n    End_Group\n"
             f"    Group = Pixels\n      Type       = {type_name}\n      ByteOrder  = {byte_order}\n"
             f"      Base       = {base}\n      Multiplier = {multiplier}\n    End_Group\n  End_Object\n"
             f"{extra_groups}End_Object\nObject = Label\n  Bytes = 4096\nEnd_Object\nEnd\n").encode()
    body = bytearray()
    if core_format == "Tile":
        for band in range(n_bands):
            for tile_row in range(-(-lines // tile_lines)):
                for tile_col in range(-(-samples // tile_samples)):
                    for r in range(tile_lines):
                        for c in range(tile_samples):
                            row, col = tile_row * tile_lines + r, tile_col * tile_samples + c
                            value = bands[band, row, col] if row < lines and col < samples else 0
                            body += np.array([value]).astype(bands.dtype).astype(dtype).tobytes()
    else:
        body += bands.astype(dtype).tobytes()
    path.write_bytes(label + b"\0" * (4096 - len(label)) + bytes(body))
    return path


def write_vicar(path, array: np.ndarray, format_name, intfmt="HIGH", realfmt="IEEE", prefix=0, header_records=0):
    lines, samples = array.shape
    dtype = {"BYTE": "u1", "HALF": "i2", "FULL": "i4", "REAL": "f4", "DOUB": "f8"}[format_name]
    order = (">" if realfmt == "IEEE" else "<") if dtype[0] == "f" else (">" if intfmt == "HIGH" else "<")
    record = prefix + samples * np.dtype(dtype).itemsize
    text = (f"LBLSIZE=512  FORMAT='{format_name}'  TYPE='IMAGE'  RECSIZE={record}  ORG='BSQ'  NL={lines}  "
            f"NS={samples}  NB=1  NBB={prefix}  NLB={header_records}  INTFMT='{intfmt}'  REALFMT='{realfmt}'  "
            f"TASK='TEST'  USER='me'").encode()
    rows = b"".join(b"\xAB" * prefix + array[r].astype(order + dtype).tobytes() for r in range(lines))
    path.write_bytes(text.ljust(512, b" ") + b"\x55" * (record * header_records) + rows)
    return path
