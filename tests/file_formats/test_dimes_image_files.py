"""Descent image files into the estimator: formats, shapes, bit depth and on-chip binning of full frames.

Every expected DN is computed here from the stated rule (DN = scale x value + offset; binned = sum of
4 rows above the ADC offset + offset, clipped), never taken from the reader's own output. Files are
real files written with OpenCV, NumPy or by hand (PDS3/VICAR/ISIS3 labels laid out explicitly).
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from planetary_files import write_isis, write_pds3, write_vicar

from file_formats.descent_images import (
    ImageDeclaration,
    InputFileError,
    bin_full_frame,
    read_descent_image,
    write_descent_image,
)

OFFSET = 20.0          # mer_a.toml adc_offset_dn
MAX_DN = 4095


@pytest.fixture(scope="module")
def binned_dn():
    rng = np.random.default_rng(5)
    return rng.integers(40, 4000, size=(256, 1024)).astype(np.uint16)


def split_rows(binned: np.ndarray) -> np.ndarray:
    """A 1024 x 1024 frame whose 4-row charge sums are exactly ``binned`` (integers: the remainder of
    (DN - offset) / 4 goes to the first rows of each block)."""
    above = binned.astype(np.int64) - int(OFFSET)
    base, remainder = np.divmod(above, 4)
    frame = np.repeat(base, 4, axis=0)
    for i in range(4):
        frame[i::4] += (remainder > i)
    return (frame + int(OFFSET)).astype(np.uint16)


def test_binned_16_bit_png_is_camera_dn_unchanged(binned_dn, mer_a, tmp_path):
    path = tmp_path / "binned.png"
    cv2.imwrite(str(path), binned_dn)
    image = read_descent_image(path, mer_a)
    assert image.dn.dtype == np.uint16 and np.array_equal(image.dn, binned_dn)
    assert not image.full_frame and image.file_format == "PNG" and "camera DN" in image.dn_rule


@pytest.mark.parametrize("suffix", [".png", ".tif", ".npy", ".raw"])
def test_full_frame_is_binned_as_on_chip(binned_dn, mer_a, tmp_path, suffix):
    frame = split_rows(binned_dn)
    assert frame.shape == (1024, 1024)
    path = tmp_path / f"frame{suffix}"
    if suffix == ".npy":
        np.save(path, frame)
    elif suffix == ".raw":
        frame.astype("<u2").tofile(path)
    else:
        cv2.imwrite(str(path), frame)
    image = read_descent_image(path, mer_a)
    assert image.full_frame and image.dn.shape == (256, 1024)
    assert np.array_equal(image.dn, binned_dn.astype(np.float32))


def test_full_frame_saturation_and_adc_clip(mer_a):
    frame = np.full((1024, 1024), 900, np.uint16)
    frame[5, 7] = 1220                     # one pixel at its full well (180000 e- / 150 + 20 DN)
    binned = bin_full_frame(frame, None, mer_a)
    assert binned[1, 7] == MAX_DN                                 # its block is saturated
    assert binned[0, 0] == 4 * (900 - OFFSET) + OFFSET == 3540
    frame[:] = 1100
    assert bin_full_frame(frame, None, mer_a)[0, 0] == MAX_DN     # 4 x 1080 + 20 = 4340: ADC clip
    frame[:] = 500
    assert bin_full_frame(frame, None, mer_a)[3, 3] == 4 * (500 - OFFSET) + OFFSET


def test_8_bit_needs_a_declaration_then_is_the_top_8_bits(mer_a, tmp_path):
    values = np.arange(256 * 1024, dtype=np.int64).reshape(256, 1024) % 256
    path = tmp_path / "eight.png"
    cv2.imwrite(str(path), values.astype(np.uint8))
    with pytest.raises(InputFileError, match=r"8-bit image without a declared bit depth; add --bits 8") as info:
        read_descent_image(path, mer_a)
    assert str(path) in str(info.value) and "\n" not in str(info.value)
    image = read_descent_image(path, mer_a, ImageDeclaration(bits=8))
    expected = (values * 16).astype(np.float32)
    expected[values == 255] = MAX_DN                              # top of the declared range: saturated
    assert np.array_equal(image.dn, expected)
    scaled = read_descent_image(path, mer_a, ImageDeclaration(dn_scale=10.0, dn_offset=20.0))
    assert np.allclose(scaled.dn, values * 10.0 + 20.0)
    with pytest.raises(InputFileError, match="does not fit the file's 8-bit samples"):
        read_descent_image(path, mer_a, ImageDeclaration(bits=12))


def test_8_bit_full_frame_holds_the_top_bits_only_up_to_a_pixels_saturation(mer_a, tmp_path):
    """One full-frame pixel saturates at 180000 e- / 150 e-/DN + 20 = 1220 DN, whose top 8 bits are
    1220 // 16 = 76: a value above 76 cannot be the top 8 bits of the DN and is refused (one line, the
    --dn-scale that states the file's range named); a file within 0..76 is read as declared."""
    path = tmp_path / "full8.png"
    frame = np.full((1024, 1024), 50, np.uint8)
    frame[8, 3] = 76                                          # at the top: saturated pixel
    cv2.imwrite(str(path), frame)
    image = read_descent_image(path, mer_a, ImageDeclaration(bits=8))
    assert image.full_frame and image.dn[0, 0] == 4 * (50 * 16 - OFFSET) + OFFSET == 3140
    assert image.dn[2, 3] == MAX_DN                               # the block of row 8 holds the saturated pixel
    frame[100, 200] = 77                                          # 77 x 16 = 1232 DN: more than a pixel holds
    cv2.imwrite(str(path), frame)
    with pytest.raises(InputFileError) as info:
        read_descent_image(path, mer_a, ImageDeclaration(bits=8))
    message = str(info.value)
    assert message.startswith(f"{path}: full frame at --bits 8: value 77 would be 1232 DN") and "\n" not in message
    assert "saturates at 1220 DN (value 76 at --bits 8" in message and "--dn-scale 4.784" in message
    stretched = read_descent_image(path, mer_a, ImageDeclaration(dn_scale=1220 / 255))   # the stated range
    assert stretched.dn[0, 0] == pytest.approx(4 * (50 * 1220 / 255 - OFFSET) + OFFSET, rel=1e-6)
    cv2.imwrite(str(tmp_path / "binned8.png"), frame[:256])       # a binned pixel holds 4 pixels' charge: no limit
    assert read_descent_image(tmp_path / "binned8.png", mer_a, ImageDeclaration(bits=8)).dn[100, 200] == 77 * 16


def test_16_bit_values_beyond_the_camera_range_need_bits_16(mer_a, tmp_path):
    values = np.random.default_rng(3).integers(0, 65535, size=(256, 1024)).astype(np.uint16)
    path = tmp_path / "full_range.png"
    cv2.imwrite(str(path), values)
    with pytest.raises(InputFileError, match=r"outside the camera's 12-bit DN range .* add --bits 16"):
        read_descent_image(path, mer_a)
    image = read_descent_image(path, mer_a, ImageDeclaration(bits=16))
    expected = values.astype(np.float32) / 16.0
    expected[values == 65535] = MAX_DN
    assert np.allclose(image.dn, expected)


def test_colour_needs_a_channel_or_luminance(mer_a, tmp_path):
    rng = np.random.default_rng(4)
    rgba = rng.integers(0, 4095, size=(256, 1024, 4)).astype(np.uint16)
    path = tmp_path / "colour.png"
    cv2.imwrite(str(path), cv2.cvtColor(rgba, cv2.COLOR_RGBA2BGRA))        # stored as R, G, B, A
    with pytest.raises(InputFileError, match=r"RGBA image \(256 x 1024 x 4\); choose one channel with --channel"):
        read_descent_image(path, mer_a)
    assert np.array_equal(read_descent_image(path, mer_a, ImageDeclaration(channel="g")).dn, rgba[:, :, 1])
    luminance = read_descent_image(path, mer_a, ImageDeclaration(luminance=True)).dn
    expected = 0.2126 * rgba[:, :, 0] + 0.7152 * rgba[:, :, 1] + 0.0722 * rgba[:, :, 2]
    assert np.allclose(luminance, expected, atol=1e-3)
    bright = tmp_path / "bright.png"               # a 16-bit colour image keeps the 16-bit rules after luminance
    cv2.imwrite(str(bright), cv2.cvtColor(rgba * 16, cv2.COLOR_RGBA2BGRA))
    with pytest.raises(InputFileError, match="outside the camera's 12-bit DN range"):
        read_descent_image(bright, mer_a, ImageDeclaration(luminance=True))
    grey = tmp_path / "grey.png"                                          # grey: the channel is moot
    cv2.imwrite(str(grey), rgba[:, :, 0])
    assert np.array_equal(read_descent_image(grey, mer_a, ImageDeclaration(channel="b")).dn, rgba[:, :, 0])


@pytest.mark.parametrize("shape", [(300, 300), (256, 512), (1024, 256), (256, 1024, 2)])
def test_other_shapes_are_refused_listing_the_accepted_ones(mer_a, tmp_path, shape):
    path = tmp_path / "odd.npy"
    np.save(path, np.zeros(shape, np.uint16))
    with pytest.raises(InputFileError) as info:
        read_descent_image(path, mer_a)
    message = str(info.value)
    assert message.startswith(f"{path}: image shape {' x '.join(map(str, shape))}; accepted: 256 x 1024")
    assert "1024 x 1024 (full frame)" in message and "\n" not in message


def test_raw_sizes_and_byte_order(binned_dn, mer_a, tmp_path):
    big = tmp_path / "big.img"
    binned_dn.astype(">u2").tofile(big)
    assert np.array_equal(read_descent_image(big, mer_a, ImageDeclaration(big_endian=True)).dn, binned_dn)
    eight = tmp_path / "eight.raw"
    (binned_dn // 16).astype(np.uint8).tofile(eight)
    assert np.array_equal(read_descent_image(eight, mer_a, ImageDeclaration(bits=8)).dn,
                          np.where(binned_dn // 16 == 255, MAX_DN, (binned_dn // 16) * 16).astype(np.float32))
    short = tmp_path / "short.raw"
    short.write_bytes(b"\0" * 1000)
    with pytest.raises(InputFileError, match=r"its 1000 bytes match no accepted shape; expected bytes: 524288 "
                                             r"\(256 x 1024\), 2097152 \(1024 x 1024\)"):
        read_descent_image(short, mer_a)


def test_float_tiff_is_dn(mer_a, tmp_path):
    values = np.random.default_rng(6).uniform(30.0, 4000.0, size=(256, 1024)).astype(np.float32)
    path = tmp_path / "float.tif"
    cv2.imwrite(str(path), values)
    image = read_descent_image(path, mer_a)
    assert image.file_format == "TIFF" and np.array_equal(image.dn, values)


def test_pds3_bit_mask_states_12_bits(binned_dn, mer_a, tmp_path):
    path = write_pds3(tmp_path / "descent.img", 256, 1024, "MSB_UNSIGNED_INTEGER", 16,
                      binned_dn.astype(">u2").tobytes(), extra_object="  SAMPLE_BIT_MASK = 2#0000111111111111#\r\n")
    image = read_descent_image(path, mer_a)
    assert image.file_format == "PDS3" and "label SAMPLE_BIT_MASK 12" in image.dn_rule
    assert np.array_equal(image.dn, binned_dn)
    frame = split_rows(binned_dn)
    full = write_pds3(tmp_path / "frame.img", 1024, 1024, "LSB_UNSIGNED_INTEGER", 16, frame.astype("<u2").tobytes())
    assert np.array_equal(read_descent_image(full, mer_a).dn, binned_dn.astype(np.float32))


def test_pds3_8_bit_and_scaled_products_need_a_declaration(binned_dn, mer_a, tmp_path):
    eight = write_pds3(tmp_path / "eight.img", 256, 1024, "UNSIGNED_INTEGER", 8, (binned_dn // 16).astype(np.uint8).tobytes(),
                       extra_object="  SAMPLE_BIT_MASK = 2#11111111#\r\n")
    with pytest.raises(InputFileError, match="8-bit image without a declared bit depth"):
        read_descent_image(eight, mer_a)
    assert np.allclose(read_descent_image(eight, mer_a, ImageDeclaration(bits=8)).dn[binned_dn < 4080],
                       (binned_dn // 16 * 16)[binned_dn < 4080])
    scaled = write_pds3(tmp_path / "scaled.img", 256, 1024, "MSB_INTEGER", 16, binned_dn.astype(">i2").tobytes(),
                        extra_object="  SCALING_FACTOR = 0.001\r\n")
    with pytest.raises(InputFileError, match=r"PDS3 product with scaled samples .* add --dn-scale"):
        read_descent_image(scaled, mer_a)
    image = read_descent_image(scaled, mer_a, ImageDeclaration(dn_scale=1000.0))
    assert np.allclose(image.dn, binned_dn, atol=0.01)


def test_vicar_and_isis3_integer_images(binned_dn, mer_a, tmp_path):
    vicar = write_vicar(tmp_path / "descent.vic", binned_dn.astype(np.int16), "HALF")
    image = read_descent_image(vicar, mer_a)
    assert image.file_format == "VICAR" and np.array_equal(image.dn, binned_dn)
    masked = tmp_path / "masked.vic"                     # a bit mask in the label: 16 significant bits
    text = vicar.read_bytes()
    label = text[:512].rstrip(b" ") + b"  PROPERTY='IMAGE_DATA'  SAMPLE_BIT_MASK='2#1111111111111111#'"
    masked.write_bytes(label.ljust(512, b" ") + text[512:])
    image = read_descent_image(masked, mer_a)
    assert "label SAMPLE_BIT_MASK 16" in image.dn_rule and np.allclose(image.dn, binned_dn / 16.0)
    cube = write_isis(tmp_path / "descent.cub", binned_dn[None].astype(np.uint16), "UnsignedWord", "Lsb",
                      core_format="BandSequential")
    image = read_descent_image(cube, mer_a)
    assert image.file_format == "ISIS3" and np.array_equal(image.dn, binned_dn)


def test_real_vicar_terrain_frame_is_refused_by_shape(mer_a):
    from conftest import REALDATA

    path = REALDATA / "moc_na" / "M12.VIC"
    if not path.exists():
        pytest.skip(f"{path} not present (../shared/realdata)")
    with pytest.raises(InputFileError, match=r"image shape 1536 x 256; accepted"):
        read_descent_image(path, mer_a, ImageDeclaration(bits=8))


def test_declaration_values_are_checked():
    with pytest.raises(InputFileError, match="--bits 10 is not allowed; allowed: 8, 12, 16"):
        ImageDeclaration(bits=10)
    with pytest.raises(InputFileError, match="--dn-scale -1.0 must be positive"):
        ImageDeclaration(dn_scale=-1.0)


def test_written_descent_images_read_back_as_the_same_dn(binned_dn, mer_a, tmp_path):
    """write_descent_image: 16-bit PNG of the DN as they are, read back without a declaration, unchanged."""
    camera = mer_a
    path = write_descent_image(tmp_path / "written.png", binned_dn)
    image = read_descent_image(path, camera)
    assert image.dn.dtype == np.uint16 and np.array_equal(image.dn, binned_dn)
    assert np.array_equal(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), binned_dn)       # no stretch, no offset
    as_float = write_descent_image(tmp_path / "float.png", binned_dn.astype(np.float64))  # whole numbers: fine
    assert np.array_equal(read_descent_image(as_float, camera).dn, binned_dn)
    for bad, message in ((binned_dn + 0.5, "whole numbers 0 to 65535"), (binned_dn.astype(np.int32) - 100, "whole numbers"),
                         (binned_dn[0], "expected a 2-D DN array")):
        with pytest.raises(InputFileError, match=message):
            write_descent_image(tmp_path / "bad.png", bad)
    with pytest.raises(InputFileError, match="allowed suffix: .png"):
        write_descent_image(tmp_path / "image.tif", binned_dn)
