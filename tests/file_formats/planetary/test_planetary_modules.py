"""The planetary reader modules one by one (pvl, layout, vicar, raster, image, sidecar, errors), on files
written here byte by byte whose every value is known: a PVL label, a VICAR BSQ image with a label and
a binary header record, a 16-bit TIFF, raw rasters with special values and a base/multiplier."""
from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from file_formats.descent_planetary import read_planetary
from file_formats.errors import InputFileError
from file_formats.planetary import image as image_module
from file_formats.planetary.isis3 import looks_like_isis3, read_isis3
from file_formats.planetary.layout import RasterLayout, apply_scaling, decode_band, describe_dtype
from file_formats.planetary.orbital_file import detect_format, load_orbital_image
from file_formats.planetary.pvl import LabelSyntaxError, Quantity, lookup, parse_label, to_plain
from file_formats.planetary.raster import looks_like_raster, read_raster
from file_formats.planetary.sidecar import default_sidecar_path
from file_formats.planetary.vicar import looks_like_ddd, looks_like_vicar, parse_vicar_label, read_vicar

LABEL = """PDS_VERSION_ID = PDS3
/* a comment */
RECORD_BYTES = 512
MAP_SCALE = 4.676 <METERS/PIXEL>
NAMES = ("A", "B", 3)
HEX = 16#FF#
OBJECT = IMAGE
  LINES = 2
  SAMPLE_TYPE = "MSB_UNSIGNED_INTEGER"
END_OBJECT = IMAGE
END
trailing bytes"""


def test_pvl_parses_values_units_lists_radix_and_objects():
    parsed = parse_label(LABEL)
    tree = parsed.tree
    assert tree["RECORD_BYTES"] == 512
    assert tree["MAP_SCALE"] == Quantity(4.676, "METERS/PIXEL")
    assert list(tree["NAMES"]) == ["A", "B", 3]
    assert tree["HEX"] == 255                                         # 16#FF#
    # the first of several alternative names, case-insensitive
    assert lookup(tree["IMAGE"], "NL", "lines") == 2 and lookup(tree, "MISSING", default=-1) == -1
    assert to_plain(tree)["IMAGE"]["SAMPLE_TYPE"] == "MSB_UNSIGNED_INTEGER"
    assert LABEL[parsed.end_offset:].lstrip("\r\n") == "trailing bytes"   # just after END and its line end


@pytest.mark.parametrize("text", ["A = 1\nOBJECT = X\nB = 2\nEND\n", "A = 1\n", "A = \nEND\n"])
def test_pvl_refuses_unbalanced_or_unterminated_labels(text):
    with pytest.raises(LabelSyntaxError):
        parse_label(text)


def test_layout_sizes_and_scaling_with_special_values():
    layout = RasterLayout(3, 4, 2, np.dtype(">i2"), "BIL", base=10.0, multiplier=0.5, invalid_raw=(-32768,),
                          valid_raw_min=-100)
    assert layout.line_bytes == 2 * 4 * 2 and layout.total_bytes == 3 * 16
    assert describe_dtype(np.dtype(">i2")) and describe_dtype(np.dtype("u1"))
    raw = np.array([[0, 4, -32768, -101], [8, 2, 1, -100]], dtype=np.int16)
    pixels, valid = apply_scaling(raw, layout)
    assert pixels.dtype == np.float32
    assert valid.tolist() == [[True, True, False, False], [True, True, True, True]]
    assert pixels.tolist() == [[10.0, 12.0, 0.0, 0.0], [14.0, 11.0, 10.5, -40.0]]   # raw * 0.5 + 10, invalid 0
    floats = np.array([[np.nan, 1.5]], dtype=np.float32)
    pixels, valid = apply_scaling(floats, RasterLayout(1, 2, 1, np.dtype("<f4")))
    assert valid.tolist() == [[False, True]] and pixels.tolist() == [[0.0, 1.5]]


def test_decode_band_reads_bsq_with_line_prefix(tmp_path):
    lines, samples = 3, 4
    data = np.arange(2 * lines * samples, dtype=">u2").reshape(2, lines, samples)   # two bands
    prefix = b"\xAA\xBB"
    path = tmp_path / "raw.bin"
    path.write_bytes(b"HDR!" + b"".join(prefix + data[b, r].tobytes() for b in range(2) for r in range(lines)))
    layout = RasterLayout(lines, samples, 2, np.dtype(">u2"), "BSQ", prefix_bytes=2)
    pixels, valid = decode_band(path, 4, layout, 1, "test raster")
    assert valid.all() and np.array_equal(pixels, data[1].astype(np.float32))


def _vicar_file(path, pixels: np.ndarray, org: str = "BSQ", nlb: int = 0):
    lines, samples = pixels.shape
    recsize = samples * 2
    text = (f"LBLSIZE={{size}}  FORMAT='HALF'  TYPE='IMAGE'  ORG='{org}'  NL={lines}  NS={samples}  NB=1  "
            f"NBB=0  NLB={nlb}  RECSIZE={recsize}  INTFMT='HIGH'  NOTE='it''s'  LIST=(1,2,3)  "
            f"TASK='FIRST'  USER='x'  ")
    size = recsize * ((len(text) + 20) // recsize + 1)
    label = text.replace("{size}", str(size)).encode("ascii").ljust(size, b"\x00")
    path.write_bytes(label + b"\x00" * (recsize * nlb) + pixels.astype(">i2").tobytes())
    return size


def test_vicar_label_and_pixels(tmp_path):
    pixels = np.array([[1, -2, 300], [4, 5, 32767]], dtype=np.int16)
    path = tmp_path / "img.vic"
    size = _vicar_file(path, pixels, nlb=1)
    head = path.read_bytes()[:64]
    assert looks_like_vicar(head) and not looks_like_ddd(head) and not looks_like_raster(head)
    label, label_size = parse_vicar_label(path)
    assert label_size == size
    assert label["NL"] == 2 and label["NS"] == 3 and label["NOTE"] == "it's" and label["LIST"] == [1, 2, 3]
    image = read_vicar(path)
    assert image.file_format == "VICAR" and image.shape == (2, 3)
    assert np.array_equal(image.pixels, pixels.astype(np.float32)) and image.valid.all()


def test_vicar_refuses_an_unknown_organisation_in_one_message(tmp_path):
    path = tmp_path / "bad.vic"
    _vicar_file(path, np.zeros((2, 2), np.int16), org="XYZ")
    with pytest.raises(image_module.ReaderError, match=r"bad\.vic: VICAR ORG = XYZ is not supported"):
        read_vicar(path)
    assert issubclass(InputFileError, ValueError)


def test_sixteen_bit_tiff_round_trips_and_a_png_is_recognised(tmp_path):
    values = np.array([[0, 1000, 65535], [7, 8, 9]], dtype=np.uint16)
    path = tmp_path / "strip.tif"
    Image.fromarray(values).save(path)
    assert looks_like_raster(path.read_bytes()[:16])
    image = read_raster(path)
    assert image.file_format == "TIFF" and image.metres_per_pixel is None
    assert np.array_equal(image.pixels, values.astype(np.float32)) and image.valid.all()
    png = tmp_path / "strip.png"
    Image.fromarray(values[:, :2].astype(np.uint8)).save(png)
    assert read_raster(png).file_format == "PNG"
    broken = tmp_path / "broken.tif"
    broken.write_bytes(path.read_bytes()[:40])
    with pytest.raises(image_module.ReaderError, match="broken.tif"):
        read_raster(broken)


def test_orbital_image_checks_its_arrays_and_sidecar_path(tmp_path):
    with pytest.raises(ValueError, match="float32"):
        image_module.OrbitalImage(np.zeros((2, 2)), np.ones((2, 2), bool), tmp_path, "TIFF")
    pixels, valid = image_module.finish(np.array([[1.0, np.inf]]), np.array([[True, True]]))
    assert pixels.tolist() == [[1.0, 0.0]] and valid.tolist() == [[True, False]]
    assert default_sidecar_path(tmp_path / "strip.IMG").parent == tmp_path


def _isis3_cube(path, raw: np.ndarray, base: float = 0.0, multiplier: float = 1.0, resolution: str = "") -> None:
    lines, samples = raw.shape
    mapping = f"  Group = Mapping\n    PixelResolution = {resolution}\n  End_Group\n" if resolution else ""
    label = ("Object = IsisCube\n  Object = Core\n    StartByte = {start}\n    Format = BandSequential\n"
             f"    Group = Dimensions\n      Samples = {samples}\n      Lines = {lines}\n      Bands = 1\n"
             "    End_Group\n    Group = Pixels\n      Type = SignedWord\n      ByteOrder = Lsb\n"
             f"      Base = {base}\n      Multiplier = {multiplier}\n    End_Group\n  End_Object\n{mapping}"
             "End_Object\nEnd\n")
    start = 1024
    text = label.replace("{start}", str(start + 1)).encode("ascii").ljust(start, b" ")
    path.write_bytes(text + raw.astype("<i2").tobytes())


def test_isis3_cube_scaling_special_pixels_and_resolution(tmp_path):
    raw = np.array([[0, 10, -32768], [20, -32752, 32767]], dtype=np.int16)   # -32768: ISIS NULL
    path = tmp_path / "strip.cub"
    _isis3_cube(path, raw, base=1.0, multiplier=0.5, resolution="4.5 <meters/pixel>")
    assert looks_like_isis3(path.read_bytes()[:64]) and detect_format(path) == "ISIS3"
    image = read_isis3(path)
    assert image.metres_per_pixel == 4.5 and image.band_count == 1
    assert image.valid.tolist() == [[True, True, False], [True, True, True]]
    # raw * 0.5 + 1 for valid pixels; the lowest valid SignedWord is -32752
    assert image.pixels.tolist() == [[1.0, 6.0, 0.0], [11.0, -16375.0, 16384.5]]
    assert np.array_equal(load_orbital_image(path).pixels, image.pixels)   # no side-car: the same image


def test_descent_planetary_returns_stored_integers_or_refuses_scaled_samples(tmp_path):
    raw = np.array([[5, 6, 7], [8, 9, 4095]], dtype=np.int16)
    plain = tmp_path / "plain.cub"
    _isis3_cube(plain, raw)
    values, kind, _ = read_planetary(plain, plain.read_bytes()[:256], dn_scale_declared=False)
    assert kind == "ISIS3" and values.dtype.kind in "iu" and values.tolist() == raw.tolist()
    scaled = tmp_path / "scaled.cub"
    _isis3_cube(scaled, raw, multiplier=2.0)
    with pytest.raises(InputFileError, match="--dn-scale"):
        read_planetary(scaled, scaled.read_bytes()[:256], dn_scale_declared=False)
    png = tmp_path / "x.png"
    Image.fromarray(np.zeros((2, 2), np.uint8)).save(png)
    assert read_planetary(png, png.read_bytes()[:256], dn_scale_declared=False) is None
