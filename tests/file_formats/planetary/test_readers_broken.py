"""Every reader rejects broken files -- truncated, wrong label, wrong dtype -- with a clear one-line error
naming the file and the keyword or format at fault, and never returns pixels.

Broken copies are made in tmp_path from hand-built files (always) and from the real samples in
../shared/realdata/ (when present).
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from planetary_files import write_isis, write_pds3, write_vicar

from file_formats.planetary import ReaderError, read_ddd, read_image, read_isis3, read_pds3, read_vicar

REALDATA = Path(__file__).resolve().parents[4] / "shared" / "realdata"


def assert_clear(call, path: Path, *words: str) -> str:
    with pytest.raises(ReaderError) as caught:
        call(path)
    message = str(caught.value)
    assert "\n" not in message, message
    assert str(path) in message, message
    for word in words:
        assert word in message, f"{word!r} not in: {message}"
    return message


def copy_real(relative: str, tmp_path: Path) -> Path:
    source = REALDATA / relative
    if not source.exists():
        pytest.skip(f"real data file {source} is absent (see ../shared/realdata/README.md)")
    target = tmp_path / source.name
    shutil.copyfile(source, target)
    target.chmod(0o644)
    return target


def truncate(path: Path, keep_fraction: float) -> Path:
    data = path.read_bytes()
    path.write_bytes(data[:int(len(data) * keep_fraction)])
    return path


def edit_label(path: Path, old: bytes, new: bytes) -> Path:
    data = path.read_bytes()
    assert data.count(old) >= 1, old
    path.write_bytes(data.replace(old, new, 1))
    return path


def small_pds3(tmp_path, **kwargs) -> Path:
    raw = np.arange(6 * 8, dtype=np.uint8).reshape(6, 8)
    return write_pds3(tmp_path / "small.img", 6, 8, "MSB_UNSIGNED_INTEGER", 8, raw.tobytes(), **kwargs)


# ---------------------------------------------------------------- truncated

def test_truncated_pds3(tmp_path):
    assert_clear(read_pds3, truncate(small_pds3(tmp_path), 0.99), "truncated", "IMAGE")


def test_truncated_real_moc_strip(tmp_path):
    path = truncate(copy_real("moc_na/M0100115_decompressed.img", tmp_path), 0.6)
    assert_clear(read_image, path, "truncated", "4864 lines x 672 samples")


def test_truncated_label_without_end(tmp_path):
    path = small_pds3(tmp_path)
    path.write_bytes(path.read_bytes()[:120])
    assert_clear(read_pds3, path, "label", "END")


def test_truncated_isis_cubes(tmp_path):
    cube = write_isis(tmp_path / "t.cub", np.ones((1, 9, 9), np.int16), "SignedWord", "Lsb")
    assert_clear(read_isis3, truncate(cube, 0.98), "truncated", "tiled ISIS3 core")
    real_cube = truncate(copy_real("moc_na/E0201461.tiny.cub", tmp_path), 0.5)
    assert_clear(read_image, real_cube, "truncated")


def test_truncated_vicar_and_ddd(tmp_path):
    vicar = write_vicar(tmp_path / "t.vic", np.ones((5, 7)), "HALF")
    assert_clear(read_vicar, truncate(vicar, 0.95), "truncated", "VICAR HALF")
    ddd = truncate(copy_real("moc_na/M12-963.DDD", tmp_path), 0.9)
    assert_clear(read_ddd, ddd, "truncated", "DDD 8-bit")
    header_only = tmp_path / "short.ddd"
    header_only.write_bytes(ddd.read_bytes()[:500])
    assert_clear(read_ddd, header_only, "1024-byte header")


def test_truncated_png_and_tiff(tmp_path):
    array = np.random.default_rng(0).integers(0, 255, size=(64, 64)).astype(np.uint8)
    Image.fromarray(array).save(tmp_path / "t.png")
    assert_clear(read_image, truncate(tmp_path / "t.png", 0.7), "corrupt or truncated")
    Image.fromarray(array).save(tmp_path / "t.tif")
    assert_clear(read_image, truncate(tmp_path / "t.tif", 0.7), "truncated TIFF", "StripOffsets")


# ---------------------------------------------------------------- wrong label

@pytest.mark.parametrize("old, new, words", [
    (b"LINES = 6", b"LINES = 60", ("truncated", "60 lines")),
    (b"LINE_SAMPLES = 8", b"LINE_SAMPLES = -8", ("LINE_SAMPLES", "positive integer")),
    (b"SAMPLE_TYPE = MSB_UNSIGNED_INTEGER", b"SAMPLE_TYPE = COMPLEX", ("SAMPLE_TYPE", "COMPLEX")),
    (b"  SAMPLE_TYPE = MSB_UNSIGNED_INTEGER\r\n", b"", ("SAMPLE_TYPE", "missing")),
    (b"END_OBJECT = IMAGE\r\n", b"", ("END_OBJECT",)),
    (b"OBJECT = IMAGE\r\n", b"", ("unexpected END_OBJECT",)),
    (b"LINES = 6", b"LINES = \x01\x02", ("non-text byte",)),
    (b"LINES = 6", b"LINES 6", ("expected '='",)),
    (b"^IMAGE = 2", b"^IMAGE = 2 <KM>", ("^IMAGE", "<BYTES>")),
    (b"^IMAGE = 2", b'^IMAGE = ("MISSING.IMG", 1)', ("MISSING.IMG", "not in")),
    (b"^IMAGE = 2", b"^TABLE = 2", ("no ^IMAGE",)),
    (b"LINES = 6", b'LINES = 6\r\n  ENCODING_TYPE = "HUFFMAN_FIRST_DIFFERENCE"', ("ENCODING_TYPE", "compressed")),
])
def test_wrong_pds3_label(tmp_path, old, new, words):
    path = edit_label(small_pds3(tmp_path), old, new)
    assert_clear(read_pds3, path, *words)


def test_pointer_inside_label_with_wrong_remaining_size_is_refused(tmp_path):
    path = copy_real("pds_isis_samples/ab102401_cropped.img", tmp_path)
    path.write_bytes(path.read_bytes() + b"\0")          # the label-end repair no longer fits exactly
    assert_clear(read_pds3, path, "^IMAGE", "inside the label")


def test_not_an_image(tmp_path):
    path = tmp_path / "notes.txt"
    path.write_text("hello, this is not an image\n")
    assert_clear(read_image, path, "unrecognised image format")


@pytest.mark.parametrize("old, new, words", [
    (b"Type       = SignedWord", b"Type       = Double", ("Core.Pixels.Type", "Double")),
    (b"ByteOrder  = Lsb", b"ByteOrder  = Vax", ("ByteOrder", "Vax")),
    (b"Format      = Tile", b"Format      = Jpeg", ("Core.Format", "Jpeg")),
    (b"StartByte   = 4097", b"StartByte   = 10", ("StartByte", "inside the label")),
    (b"TileSamples = 4", b"TileSamples = 0", ("TileSamples",)),
    (b"Lines   = 9", b"Lines   = 90", ("truncated",)),
    (b"End_Object\nObject = Label", b"Object = Label", ("IsisCube", "END")),
])
def test_wrong_isis_label(tmp_path, old, new, words):
    cube = write_isis(tmp_path / "w.cub", np.ones((1, 9, 9), np.int16), "SignedWord", "Lsb")
    assert_clear(read_isis3, edit_label(cube, old, new), *words)


@pytest.mark.parametrize("old, new, words", [
    (b"FORMAT='HALF'", b"FORMAT='COMP'", ("FORMAT", "COMP")),
    (b"RECSIZE=14", b"RECSIZE=16", ("RECSIZE",)),
    (b"REALFMT='IEEE'", b"REALFMT='VAX' ", ()),            # irrelevant for HALF: still reads
    (b"INTFMT='HIGH'", b"INTFMT='VAXX'", ("INTFMT", "VAXX")),
    (b"NL=5", b"NL=x", ("NL",)),
    (b"LBLSIZE=512", b"LBLSIZE=9e9", ("LBLSIZE",)),
])
def test_wrong_vicar_label(tmp_path, old, new, words):
    path = edit_label(write_vicar(tmp_path / "w.vic", np.arange(35).reshape(5, 7), "HALF"), old, new)
    if not words:
        np.testing.assert_array_equal(read_vicar(path).pixels, np.arange(35).reshape(5, 7))
        return
    assert_clear(read_image if old.startswith(b"LBLSIZE") else read_vicar, path, *words)


def test_vicar_vax_reals_refused(tmp_path):
    path = write_vicar(tmp_path / "r.vic", np.ones((2, 2)), "REAL")
    assert_clear(read_vicar, edit_label(path, b"REALFMT='IEEE'", b"REALFMT='VAX' "), "REALFMT", "VAX")


def test_wrong_ddd_header(tmp_path):
    ddd = copy_real("moc_na/M12-963.DDD", tmp_path)
    data = bytearray(ddd.read_bytes())
    bad_magic = tmp_path / "magic.ddd"
    bad_magic.write_bytes(b"\0\0\x06\x7c" + bytes(data[4:]))
    assert_clear(read_ddd, bad_magic, "magic number 1660")
    lines_disagree = tmp_path / "lines.ddd"
    lines_disagree.write_bytes(bytes(data[:4]) + (1000).to_bytes(4, "big") + bytes(data[8:]))
    assert_clear(read_ddd, lines_disagree, "disagree", "down 1536")


# ---------------------------------------------------------------- wrong dtype

@pytest.mark.parametrize("old, new, words", [
    (b"SAMPLE_BITS = 8", b"SAMPLE_BITS = 12", ("SAMPLE_BITS = 12", "allowed: 8, 16, 32")),
    (b"SAMPLE_BITS = 8", b"SAMPLE_BITS = 16", ("truncated",)),          # 16-bit label on 8-bit data
    (b"SAMPLE_TYPE = MSB_UNSIGNED_INTEGER", b"SAMPLE_TYPE = VAX_REAL", ("VAX",)),
    (b"SAMPLE_TYPE = MSB_UNSIGNED_INTEGER", b"SAMPLE_TYPE = IEEE_REAL", ("SAMPLE_BITS = 8", "IEEE_REAL")),
])
def test_wrong_pds3_dtype(tmp_path, old, new, words):
    assert_clear(read_pds3, edit_label(small_pds3(tmp_path), old, new), *words)


def test_wrong_dtype_real_moc_label(tmp_path):
    path = copy_real("moc_na/M0100115_decompressed.img", tmp_path)
    edit_label(path, b"SAMPLE_BITS = 8", b"SAMPLE_BITS = 16")
    assert_clear(read_image, path, "truncated", "MSB uint16")


def test_wrong_isis_dtype_float_label_on_int16_data(tmp_path):
    cube = write_isis(tmp_path / "d.cub", np.ones((1, 9, 9), np.int16), "SignedWord", "Lsb")
    edit_label(cube, b"Type       = SignedWord", b"Type       = Real      ")
    assert_clear(read_isis3, cube, "truncated")


def test_wrong_ddd_bits(tmp_path):
    ddd = copy_real("moc_na/M12-963.DDD", tmp_path)
    data = ddd.read_bytes()
    ddd.write_bytes(data[:12] + (12).to_bytes(4, "big") + data[16:])
    assert_clear(read_ddd, ddd, "bits-per-pixel", "12")


def test_bilevel_png_refused(tmp_path):
    Image.fromarray(np.zeros((8, 8), dtype=bool)).save(tmp_path / "bits.png")
    assert_clear(read_image, tmp_path / "bits.png", "mode '1'")
