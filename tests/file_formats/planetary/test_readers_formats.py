"""Reader behaviour on small files written here by hand (label text and bytes laid out explicitly).

Covers what the real samples do not: byte orders, base/multiplier, ISIS special pixels and partial
tiles, detached PDS3 labels, VICAR prefixes, GeoTIFF scale, and the side-car and load_terrain rules.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image, TiffImagePlugin
from planetary_files import write_isis, write_pds3, write_vicar

from config_tables.errors import ConfigError
from file_formats.planetary import ReaderError, read_image, read_isis3, read_pds3, read_sidecar, read_vicar
from sitedata.terrain.real_terrain import load_terrain

ISIS_NULL4, ISIS_HRS4 = 0xFF7FFFFB, 0xFF7FFFFF


def test_pds3_lsb_int16_prefix_offset_scaling_and_missing_constant(tmp_path):
    raw = np.array([[1, -2, 3], [-32768, 5, 600]], dtype="<i2")
    data = b"".join(b"PP" + raw[r].tobytes() + b"S" for r in range(2))
    path = write_pds3(tmp_path / "a.img", 2, 3, "LSB_INTEGER", 16, data,
                      "  LINE_PREFIX_BYTES = 2\r\n  LINE_SUFFIX_BYTES = 1\r\n  OFFSET = 10.0\r\n"
                      "  SCALING_FACTOR = 0.5\r\n  MISSING_CONSTANT = -32768\r\n")
    image = read_pds3(path)
    np.testing.assert_array_equal(image.valid, [[True, True, True], [False, True, True]])
    np.testing.assert_array_equal(image.pixels, [[10.5, 9.0, 11.5], [0.0, 12.5, 310.0]])


def test_pds3_map_scale_and_angles_from_label(tmp_path):
    path = write_pds3(tmp_path / "m.img", 2, 2, "UNSIGNED_INTEGER", 8, bytes([1, 2, 3, 4]),
                      extra_top="INCIDENCE_ANGLE = 40.0 <DEG>\r\nEMISSION_ANGLE = 5.0\r\nPHASE_ANGLE = 42.0 <DEG>\r\n"
                                "OBJECT = IMAGE_MAP_PROJECTION\r\n  MAP_SCALE = 0.0065 <KM/PIXEL>\r\n"
                                "END_OBJECT = IMAGE_MAP_PROJECTION\r\n")
    image = read_pds3(path)
    assert image.metres_per_pixel == pytest.approx(6.5)
    assert (image.incidence_rad, image.emission_rad, image.phase_rad) == pytest.approx(
        (math.radians(40), math.radians(5), math.radians(42)))


def test_pds3_detached_label_found_beside_data_file(tmp_path):
    array = np.arange(12, dtype=">f4").reshape(3, 4) * 0.25
    (tmp_path / "scene.img").write_bytes(b"\0" * 100 + array.astype(">f4").tobytes())
    (tmp_path / "scene.lbl").write_text(
        'PDS_VERSION_ID = PDS3\nRECORD_TYPE = UNDEFINED\n^IMAGE = ("SCENE.IMG", 101 <BYTES>)\n'
        "OBJECT = IMAGE\n LINES = 3\n LINE_SAMPLES = 4\n SAMPLE_TYPE = IEEE_REAL\n SAMPLE_BITS = 32\n"
        "END_OBJECT\nEND\n")
    for given in ("scene.img", "scene.lbl"):
        image = read_image(tmp_path / given)
        np.testing.assert_array_equal(image.pixels, array)
        assert image.source == tmp_path / "scene.img"


def test_pds3_detached_label_with_record_pointer_refers_to_the_data_file(tmp_path):
    array = np.arange(20, dtype=np.uint8).reshape(4, 5)
    (tmp_path / "strip.img").write_bytes(b"\xFF" * 10 + array.tobytes())
    (tmp_path / "strip.lbl").write_text("PDS_VERSION_ID = PDS3\nRECORD_TYPE = FIXED_LENGTH\nRECORD_BYTES = 5\n"
                                        "^IMAGE = 3\nOBJECT = IMAGE\n LINES = 4\n LINE_SAMPLES = 5\n"
                                        " SAMPLE_TYPE = UNSIGNED_INTEGER\n SAMPLE_BITS = 8\nEND_OBJECT\nEND\n")
    image = read_image(tmp_path / "strip.img")
    np.testing.assert_array_equal(image.pixels, array)


def test_isis_tiled_msb_signed_word_partial_tiles_specials_and_scaling(tmp_path):
    rng = np.random.default_rng(3)
    raw = rng.integers(-1000, 1000, size=(1, 9, 10)).astype(np.int16)
    raw[0, 0, 0], raw[0, 8, 9], raw[0, 4, 5] = -32768, -32764, -32766      # NULL, HRS, LIS
    path = write_isis(tmp_path / "w.cub", raw, "SignedWord", "Msb", tile=(4, 4), base=100.0, multiplier=0.5)
    image = read_isis3(path)
    special = np.zeros((9, 10), dtype=bool)
    special[0, 0] = special[8, 9] = special[4, 5] = True
    np.testing.assert_array_equal(image.valid, ~special)
    np.testing.assert_array_equal(image.pixels[~special], raw[0][~special] * 0.5 + 100.0)
    assert (image.pixels[special] == 0).all()


def test_isis_bsq_byte_second_band_and_real_specials(tmp_path):
    bands = np.stack([np.full((3, 5), 7), np.arange(15).reshape(3, 5) % 256]).astype(np.uint8)
    image = read_isis3(write_isis(tmp_path / "b.cub", bands, "UnsignedByte", "Lsb", "BandSequential"), band_index=1)
    np.testing.assert_array_equal(image.pixels, bands[1])
    np.testing.assert_array_equal(image.valid, (bands[1] >= 1) & (bands[1] <= 254))   # 0 is NULL
    real = np.array([[[0.25, 0.5], [0.75, 1.0]]], dtype=np.float32)
    real.view(np.uint32)[0, 0, 1] = ISIS_NULL4
    real.view(np.uint32)[0, 1, 0] = ISIS_HRS4
    calibrated = write_isis(tmp_path / "f.cub", real, "Real", "Msb", tile=(2, 2),
                            extra_groups="  Group = Radiometry\n    iof = 0.03\n  End_Group\n")
    image = read_isis3(calibrated)
    np.testing.assert_array_equal(image.valid, [[True, False], [False, True]])
    np.testing.assert_array_equal(image.pixels, [[0.25, 0.0], [0.0, 1.0]])
    assert (image.dn_to_if_scale, image.dn_to_if_offset) == (1.0, 0.0)


@pytest.mark.parametrize("format_name, intfmt, realfmt, prefix, header", [
    ("HALF", "LOW", "IEEE", 4, 2), ("HALF", "HIGH", "IEEE", 0, 0), ("REAL", "HIGH", "RIEEE", 0, 1),
    ("REAL", "LOW", "IEEE", 3, 0), ("BYTE", "HIGH", "IEEE", 0, 0)])
def test_vicar_formats_byte_orders_and_prefixes(tmp_path, format_name, intfmt, realfmt, prefix, header):
    array = (np.arange(24).reshape(4, 6) * 3 - (0 if format_name == "BYTE" else 20)).astype(float)
    if format_name == "REAL":
        array = array / 7.0
    path = write_vicar(tmp_path / "v.vic", array, format_name, intfmt, realfmt, prefix, header)
    image = read_vicar(path)
    np.testing.assert_allclose(image.pixels, array.astype(np.float32))


def _geotiff(path, scale=(2.5, 2.5), model_type=1, units=9001):
    ifd = TiffImagePlugin.ImageFileDirectory_v2()
    ifd[33550] = (scale[0], scale[1], 0.0)
    ifd.tagtype[33550] = 12
    ifd[34735] = (1, 1, 0, 2, 1024, 0, 1, model_type, 3076, 0, 1, units)
    ifd.tagtype[34735] = 3
    array = np.arange(30 * 40, dtype=np.float32).reshape(30, 40) / 100.0
    Image.fromarray(array, mode="F").save(path, tiffinfo=ifd)
    return array


def test_geotiff_scale_geographic_and_non_square(tmp_path):
    array = _geotiff(tmp_path / "g.tif")
    image = read_image(tmp_path / "g.tif")
    assert image.file_format == "GeoTIFF" and image.metres_per_pixel == 2.5
    np.testing.assert_array_equal(image.pixels, array)
    _geotiff(tmp_path / "deg.tif", scale=(1e-4, 1e-4), model_type=2)
    geographic = read_image(tmp_path / "deg.tif")
    assert geographic.metres_per_pixel is None and any("GTModelTypeGeoKey" in n for n in geographic.notes)
    _geotiff(tmp_path / "rect.tif", scale=(2.0, 3.0))
    with pytest.raises(ReaderError, match="non-square"):
        read_image(tmp_path / "rect.tif")


def test_png_alpha_marks_invalid_and_colour_is_refused(tmp_path):
    gray = np.arange(20, dtype=np.uint8).reshape(4, 5) * 10
    alpha = np.full((4, 5), 255, dtype=np.uint8)
    alpha[1, 2] = 0
    Image.fromarray(np.dstack([gray, alpha]), mode="LA").save(tmp_path / "la.png")
    image = read_image(tmp_path / "la.png")
    np.testing.assert_array_equal(image.valid, alpha > 0)
    np.testing.assert_array_equal(image.pixels[image.valid], gray[alpha > 0])
    Image.fromarray(np.zeros((4, 5, 3), dtype=np.uint8), mode="RGB").save(tmp_path / "rgb.png")
    with pytest.raises(ReaderError, match="mode 'RGB'"):
        read_image(tmp_path / "rgb.png")


def _sidecar(tmp_path, text, name="side.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_sidecar_validation_errors_name_file_and_field(tmp_path):
    with pytest.raises(ConfigError, match=r"side\.toml: metres_per_pixle is not a known field; allowed: name, metres_per_pixel"):
        read_sidecar(_sidecar(tmp_path, "metres_per_pixle = 3.0\n"))
    with pytest.raises(ConfigError, match="phase_deg = 80 is impossible"):
        read_sidecar(_sidecar(tmp_path, "incidence_deg = 30.0\nemission_deg = 10.0\nphase_deg = 80.0\n"))
    with pytest.raises(ConfigError, match="incidence_deg = 95 is out of range"):
        read_sidecar(_sidecar(tmp_path, "incidence_deg = 95.0\n"))
    with pytest.raises(ConfigError, match="crop.height is not a known field; allowed: first_row, first_col, rows, cols"):
        read_sidecar(_sidecar(tmp_path, "[crop]\nheight = 3\n"))


FULL_SIDECAR = ("metres_per_pixel = 3.0\nincidence_deg = 40.0\nemission_deg = 10.0\nphase_deg = 45.0\n"
                "dn_to_if_scale = 0.002\ndn_to_if_offset = 0.01\n")


def test_load_terrain_applies_sidecar_crop_and_fills_invalid_pixels(tmp_path):
    raw = (np.arange(8 * 10).reshape(8, 10) + 10).astype(np.uint8)
    raw[3, 4] = 0                                                        # MISSING_CONSTANT
    image_path = write_pds3(tmp_path / "strip.img", 8, 10, "UNSIGNED_INTEGER", 8, raw.tobytes(),
                            "  MISSING_CONSTANT = 0\r\n")
    _sidecar(tmp_path, FULL_SIDECAR + "[crop]\nfirst_row = 2\nfirst_col = 3\nrows = 4\ncols = 5\n", "strip.toml")
    terrain = load_terrain(image_path)                                   # side-car found by stem
    window = raw[2:6, 3:8].astype(float)
    expected = window * 0.002 + 0.01
    expected[1, 1] = np.nan                                              # the missing pixel (3, 4)
    neighbours = [expected[0, 1], expected[2, 1], expected[1, 0], expected[1, 2]]
    got = terrain.reflectance_if
    assert got.shape == (4, 5) and terrain.metres_per_pixel == 3.0
    np.testing.assert_allclose(got[~np.isnan(expected)], expected[~np.isnan(expected)], rtol=1e-6)
    assert any(np.isclose(got[1, 1], value) for value in neighbours)
    assert terrain.moc_phase_rad == pytest.approx(math.radians(45.0))
    assert terrain.name == "strip"
    assert terrain.pixel_to_world(1.5, 2.0) == pytest.approx((0.0, 0.0))    # grid centred on the origin


def test_load_terrain_sidecar_overrides_file_and_requires_calibration(tmp_path):
    bands = np.full((1, 4, 4), 0.2, dtype=np.float32)
    cube = write_isis(tmp_path / "c.cub", bands, "Real", "Lsb", tile=(4, 4))
    side = _sidecar(tmp_path, "metres_per_pixel = 3.0\nincidence_deg = 40.0\nemission_deg = 10.0\n"
                              "phase_deg = 45.0\n")
    with pytest.raises(ReaderError, match="dn_to_if_scale"):            # no Radiometry group: DN
        load_terrain(cube, side)
    _sidecar(tmp_path, FULL_SIDECAR, "full.toml")
    terrain = load_terrain(cube, tmp_path / "full.toml")
    np.testing.assert_allclose(terrain.reflectance_if, 0.2 * 0.002 + 0.01, rtol=1e-6)


def test_load_terrain_refuses_mostly_invalid_and_negative_if(tmp_path):
    raw = np.zeros((4, 4), dtype=np.uint8)
    raw[0, :3] = 50
    path = write_pds3(tmp_path / "holes.img", 4, 4, "UNSIGNED_INTEGER", 8, raw.tobytes(), "  MISSING_CONSTANT = 0\r\n")
    _sidecar(tmp_path, FULL_SIDECAR, "holes.toml")
    with pytest.raises(ReaderError, match="only 18.8 % of the pixels are valid"):
        load_terrain(path)
    bright = write_pds3(tmp_path / "neg.img", 2, 2, "UNSIGNED_INTEGER", 8, bytes([10, 20, 30, 40]))
    side = _sidecar(tmp_path, FULL_SIDECAR.replace("dn_to_if_offset = 0.01", "dn_to_if_offset = -0.05"), "n.toml")
    with pytest.raises(ReaderError, match="negative I/F"):
        load_terrain(bright, side)
