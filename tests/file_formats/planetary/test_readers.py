"""Terrain readers on the real mission files in ../shared/realdata/ (skipped when that folder is absent).

Expected values come from the files themselves, located by hand from their labels (byte offsets
computed here from RECORD_BYTES, pointers, tile sizes), never from the readers' own output.
"""
from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from file_formats.planetary import ReaderError, detect_format, read_ddd, read_image, read_isis3, read_pds3, read_vicar
from sitedata.terrain.real_terrain import load_terrain

REPO = Path(__file__).resolve().parents[3]
REALDATA = REPO.parent / "shared" / "realdata"
EXAMPLES = REPO / "sitedata" / "examples"


def real(relative: str) -> Path:
    path = REALDATA / relative
    if not path.exists():
        pytest.skip(f"real data file {path} is absent (see ../shared/realdata/README.md)")
    return path


def raw_bytes(path: Path, offset: int, count: int, dtype: str = "u1") -> np.ndarray:
    with path.open("rb") as handle:
        handle.seek(offset)
        return np.frombuffer(handle.read(count * np.dtype(dtype).itemsize), dtype=dtype)


def test_moc_na_decompressed_strip_matches_its_bytes():
    path = real("moc_na/M0100115_decompressed.img")
    image = read_pds3(path)
    assert image.shape == (4864, 672) and image.pixels.dtype == np.float32
    # Label: RECORD_BYTES = 672, ^IMAGE = 5 -> data start after 4 records.
    expected = raw_bytes(path, 4 * 672, 4864 * 672).reshape(4864, 672)
    np.testing.assert_array_equal(image.pixels, expected.astype(np.float32))
    assert image.valid.all()
    assert image.metres_per_pixel is None and image.incidence_rad is None and image.dn_to_if_scale is None
    assert image.label["INSTRUMENT_ID"] == "MOC-NA"
    assert detect_format(path) == "PDS3"


def test_moc_predictively_compressed_imq_decodes_to_the_msss_decompressed_product():
    # pdr's port of the MSSS decompressor against the MSSS-decompressed product, read as raw bytes
    compressed, decompressed = real("moc_na/M0100115.imq"), real("moc_na/M0100115_decompressed.img")
    image = read_image(compressed)
    expected = raw_bytes(decompressed, 4 * 672, 4864 * 672).reshape(4864, 672)   # RECORD_BYTES 672, ^IMAGE = 5
    assert image.shape == (4864, 672) and image.valid.all()
    np.testing.assert_array_equal(image.pixels, expected.astype(np.float32))
    assert any("MOC-PRED-X-5" in note and "pdr" in note for note in image.notes)
    assert image.label["IMAGE"]["ENCODING_TYPE"] == "MOC-PRED-X-5"


def test_moc_transform_compression_is_still_refused_naming_encoding_type(tmp_path):
    source = real("moc_na/M0100115.imq")
    path = tmp_path / "transform.imq"
    path.write_bytes(source.read_bytes().replace(b'"MOC-PRED-X-5"', b'"MOC-DCT-2"  ', 1))
    with pytest.raises(ReaderError) as caught:
        read_image(path)
    message = str(caught.value)
    assert str(path) in message and "ENCODING_TYPE" in message and "MOC-DCT-2" in message
    assert "\n" not in message


def test_isis_tiled_float_cube_reassembles_tiles():
    path = real("moc_na/E0201461.tiny.cub")
    image = read_isis3(path)
    assert image.shape == (500, 500)
    assert image.metres_per_pixel == pytest.approx(4.6762765656263)
    assert (image.dn_to_if_scale, image.dn_to_if_offset) == (1.0, 0.0)
    # Locate pixels by hand: StartByte 65537, 128x128 tiles, 4 tiles across, LSB float32.
    rng = np.random.default_rng(1)
    for row, col in rng.integers(0, 500, size=(40, 2)):
        tile = (row // 128) * 4 + col // 128
        item = tile * 128 * 128 + (row % 128) * 128 + col % 128
        expected = raw_bytes(path, 65536 + 4 * item, 1, "<f4")[0]
        assert image.pixels[row, col] == expected
    # Physical I/F of a sunlit Mars scene, and no seams at tile boundaries.
    assert 0.05 < image.pixels.min() and image.pixels.max() < 0.5
    pixels = image.pixels.astype(float)
    row_steps = np.abs(np.diff(pixels, axis=0)).mean(axis=1)
    seams = row_steps[[127, 255, 383]]
    assert seams.max() < 2.0 * np.median(row_steps)


@pytest.mark.parametrize("name, type_code, low, high", [("mocImage.cub", "u1", 1, 254),
                                                         ("ctxTestImage.cub", "<i2", -32752, 32767)])
def test_small_isis_cubes_integer_types(name, type_code, low, high):
    path = real(f"pds_isis_samples/{name}")
    image = read_isis3(path)
    expected = raw_bytes(path, 65536, 400, type_code).reshape(20, 20)  # one 20x20 tile
    np.testing.assert_array_equal(image.pixels, expected.astype(np.float32))
    assert image.valid.all() == bool(((expected >= low) & (expected <= high)).all())


def test_vicar_and_ddd_hold_the_same_pixels():
    vicar = read_vicar(real("moc_na/M12.VIC"))
    ddd = read_ddd(real("moc_na/M12-963.DDD"))
    assert vicar.shape == ddd.shape == (1536, 256)
    np.testing.assert_array_equal(vicar.pixels, ddd.pixels)
    # VICAR: LBLSIZE=512, BYTE, NBB=0, NLB=0; DDD: 1024-byte header.
    np.testing.assert_array_equal(vicar.pixels.ravel(), raw_bytes(real("moc_na/M12.VIC"), 512, 1536 * 256))
    assert vicar.pixels.std() > 1.0


def test_hirise_edr_line_prefix_suffix_and_missing_constant():
    path = real("pds_isis_samples/PSP_001446_1790_BG12_0.IMG")
    image = read_pds3(path)
    assert image.shape == (5000, 256)
    # ^IMAGE = 61903 <BYTES>; each line: 18 prefix + 256 samples + 16 suffix bytes.
    records = raw_bytes(path, 61902, 5000 * 290).reshape(5000, 290)
    expected = records[:, 18:18 + 256]
    np.testing.assert_array_equal(image.valid, expected != 255)          # MISSING_CONSTANT = 16#FF#
    np.testing.assert_array_equal(image.pixels[image.valid], expected[expected != 255].astype(np.float32))


def test_themis_qube_band_with_core_null_and_scaling():
    path = real("pds_isis_samples/V00821003RDR_cropped.QUB")
    image = read_pds3(path, band_index=2)
    assert image.shape == (200, 1024) and image.band_count == 5
    # Raw qube at byte 2848, BSQ (SAMPLE, LINE, BAND), MSB int16.
    raw = raw_bytes(path, 2848 + 2 * 2 * 200 * 1024, 200 * 1024, ">i2").reshape(200, 1024)
    np.testing.assert_array_equal(image.valid, raw >= -32752)
    assert not image.valid.all() and image.valid.any()
    expected = raw[raw >= -32752] * 7.085889e-08 + 0.00283896
    np.testing.assert_allclose(image.pixels[image.valid], expected, rtol=1e-6)


@pytest.mark.parametrize("name, shape, label_end, dtype, prefix", [
    ("ab102401_cropped.img", (5, 640), 1165, "u1", 0),
    ("h0279_0000_re2_cropped.img", (5, 1288), 4396, ">i2", 68)])
def test_products_with_pointer_inside_label_read_from_label_end(name, shape, label_end, dtype, prefix):
    path = real(f"pds_isis_samples/{name}")
    image = read_pds3(path)
    assert image.shape == shape and any("inside the label" in note for note in image.notes)
    item = np.dtype(dtype).itemsize
    record = prefix + shape[1] * item
    records = raw_bytes(path, label_end, shape[0] * record).reshape(shape[0], record)
    expected = np.ascontiguousarray(records[:, prefix:]).view(dtype)
    np.testing.assert_array_equal(image.pixels, expected.astype(np.float32))
    # Aligned data are smooth along a line; a misplaced start would break that.
    assert np.abs(np.diff(image.pixels, axis=1)).mean() < 0.2 * image.pixels.std() + 2.0


def test_hrsc_reflectance_scaling_factor_is_the_dn_to_if():
    image = read_pds3(real("pds_isis_samples/h0279_0000_re2_cropped.img"))
    assert image.dn_to_if_scale == pytest.approx(0.00210933)
    assert 0.05 < image.dn_to_if_scale * image.pixels.mean() < 0.4          # a Mars I/F


def test_ctx_png_tiles_read_as_grayscale():
    for letter in "ABCDEF":
        image = read_image(real(f"ctx_tiles/MC11E-{letter}.png"))
        assert image.shape == (2000, 2000) and image.file_format == "PNG"
        assert image.valid.all() and 0 <= image.pixels.min() and image.pixels.max() <= 255
        assert image.metres_per_pixel is None


def test_load_terrain_refuses_unknown_scale_and_angles():
    with pytest.raises(ReaderError, match="metres_per_pixel"):
        load_terrain(real("moc_na/M0100115_decompressed.img"), sidecar=None)
    with pytest.raises(ReaderError, match="incidence_deg"):
        load_terrain(real("moc_na/E0201461.tiny.cub"))                 # scale known, angles not


def test_real_moc_example_campaign_terrain():
    real("moc_na/M0100115_decompressed.img")
    from sitedata.sites import load_class_terrain, load_site

    toml_path = EXAMPLES / "real_moc.toml"
    site = load_site(toml_path)
    (klass,) = site.classes
    assert klass.terrain.kind == "file" and klass.ellipse_fraction == 1.0 and 0 < klass.cases <= 50
    assert site.camera_path.is_file()
    terrain = load_class_terrain(klass.terrain)
    with klass.terrain.sidecar.open("rb") as handle:
        sidecar = tomllib.load(handle)
    assert terrain.shape == (4864, 672)
    assert terrain.metres_per_pixel == sidecar["metres_per_pixel"] == pytest.approx(4.5, abs=0.5)
    west, east, south, north = terrain.extent_m
    assert east - west == pytest.approx(672 * 4.5) and north - south == pytest.approx(4864 * 4.5)
    assert west == pytest.approx(-east) and south == pytest.approx(-north)       # centred on (0, 0)
    assert terrain.moc_incidence_rad == pytest.approx(math.radians(sidecar["incidence_deg"]))
    assert terrain.moc_phase_rad == pytest.approx(math.radians(sidecar["phase_deg"]))
    dn = raw_bytes(klass.terrain.path, 4 * 672, 4864 * 672).reshape(4864, 672)
    np.testing.assert_allclose(terrain.reflectance_if, dn * sidecar["dn_to_if_scale"], rtol=1e-6)
    assert 0.1 < terrain.reflectance_if.mean() < 0.3 and np.isfinite(terrain.reflectance_if).all()


@pytest.mark.slow
def test_inspect_command_reports_missing_terrain_facts(capsys):
    from file_formats.planetary.inspect_files import main

    good, compressed = real("moc_na/M0100115_decompressed.img"), real("moc_na/M0100115.imq")
    assert main([str(good)]) == 0
    out = capsys.readouterr().out
    assert "4864 rows x 672 cols" in out and "metres_per_pixel  unknown (side-car needed)" in out
    assert main([str(good), "--sidecar", str(EXAMPLES / "M0100115.sidecar.toml")]) == 0
    assert "metres_per_pixel  4.5 m" in capsys.readouterr().out
    assert main([str(compressed)]) == 0
    assert "decoded with pdr" in capsys.readouterr().out
