"""Descent image files -> the binned camera DN the estimator takes, with nothing guessed.

Formats (recognised by their first bytes, not the extension)
--------------------------------------------------------------
PNG and TIFF (8- or 16-bit integer, or float TIFF; grey, RGB or RGBA), NumPy ``.npy`` (2-D or
3-D integer or float array), PDS3 ``.IMG`` (attached or detached label), VICAR and ISIS3 ``.cub``
(read by :mod:`file_formats.planetary`: special pixels become 0 DN, i.e. "no signal"), and anything else
as headerless raw samples (``uint16``, little-endian unless ``big_endian``; ``uint8`` with
``bits = 8``) whose byte count must match one of the accepted shapes.

Shapes
------
``(H / b) x W`` (256 x 1024 for MER: rows binned ``b``:1 on chip, as the camera returns them) is
taken as binned. ``H x W`` (1024 x 1024, a full frame) is binned here as the camera does it on chip:
the charges of ``b`` adjacent rows are summed before one read, so with the ADC offset ``o`` ::

    DN_binned[k, j] = min(sum_{i < b} (DN[b k + i, j] - o) + o, DN_max)

and a binned pixel is saturated (set to ``DN_max``) when any of its ``b`` pixels is at or above the
single-pixel saturation level ``min(DN_max, full_well / gain + o)``. What a full-frame read differs
in (``b`` reads instead of one, so ``b`` times the read-noise variance; a longer storage-area wait)
is not undone. A full frame declared with fewer bits than the ADC's (``--bits 8``: DN = 16 x value)
can only hold values up to the top bits of that saturation level (76 for MER's 1220 DN); a larger value
is refused, since the file is then a stretch or look-up table of the DN, whose range ``--dn-scale``
states (e.g. ``--dn-scale 4.784`` for 0..255 spanning 0..1220 DN). RGB/RGBA images need ``channel`` (r, g or b) or ``luminance`` (Rec. 709:
``0.2126 R + 0.7152 G + 0.0722 B``; alpha is ignored; grey images ignore both). Any other shape is refused with the list
of accepted shapes.

DN scale (never guessed)
------------------------
Stored values become camera DN by ``DN = scale x value + offset``:

* ``dn_scale`` (and ``dn_offset``, default 0) declared: used as given;
* ``bits`` declared (8, 12 or 16), or the significant bits read from a label (PDS3
  ``SAMPLE_BIT_MASK``): the values are the top ``bits`` bits of the camera's ``adc_bits``-bit DN,
  ``scale = 2^(adc_bits - bits)`` (8 -> x16, 12 -> x1, 16 -> /16 for MER), ``offset = dn_offset``;
  a value at the declared maximum ``2^bits - 1`` is saturated (camera ``DN_max``); a value above it
  is refused;
* 16-bit and wider integer containers without a declaration hold camera DN as they are (the
  simulator's own convention); a value above the camera's ``DN_max`` is refused (declare
  ``bits = 16`` if the values fill 16 bits); float arrays are DN as they are;
* 8-bit containers without a declaration are refused: an 8-bit value may be the top 8 bits of the
  DN, a companded (look-up table) value or a display stretch, and only the user knows which.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from PIL import Image

from file_formats.descent_planetary import read_planetary
from file_formats.errors import InputFileError

LUMINANCE_WEIGHTS = (0.2126, 0.7152, 0.0722)        # Rec. 709, applied to R, G, B as stored
CHANNELS = {"r": 0, "g": 1, "b": 2, "0": 0, "1": 1, "2": 2}
ALLOWED_BITS = (8, 12, 16)


@dataclass(frozen=True)
class ImageDeclaration:
    """What the user states about image files (the command line's ``--bits``, ``--dn-scale`` ...).

    Attributes
    ----------
    bits : int or None
        Significant bits of the stored values (8, 12 or 16).
    dn_scale, dn_offset : float or None
        ``DN = dn_scale * value + dn_offset`` (``dn_offset`` also applies with ``bits``).
    channel : str or None
        "r", "g" or "b" (or "0", "1", "2") for RGB/RGBA images.
    luminance : bool
        Use the Rec. 709 luminance of an RGB/RGBA image.
    big_endian : bool
        Raw 16-bit samples are big-endian.
    """

    bits: int | None = None
    dn_scale: float | None = None
    dn_offset: float | None = None
    channel: str | None = None
    luminance: bool = False
    big_endian: bool = False

    def __post_init__(self):
        if self.bits is not None and self.bits not in ALLOWED_BITS:
            raise InputFileError(f"--bits {self.bits} is not allowed; allowed: 8, 12, 16")
        if self.channel is not None and str(self.channel).lower() not in CHANNELS:
            raise InputFileError(f"--channel {self.channel} is not allowed; allowed: r, g, b (or 0, 1, 2)")
        if self.channel is not None and self.luminance:
            raise InputFileError("--channel and --luminance exclude each other; give one")
        for name in ("dn_scale", "dn_offset"):
            value = getattr(self, name)
            if value is not None and not np.isfinite(value):
                raise InputFileError(f"--{name.replace('_', '-')} {value} must be a finite number")
        if self.dn_scale is not None and self.dn_scale <= 0:
            raise InputFileError(f"--dn-scale {self.dn_scale} must be positive")


@dataclass(frozen=True)
class DescentImageFile:
    """One image file read as binned camera DN.

    Attributes
    ----------
    dn : ndarray, (H / b, W)
        Binned camera DN (``uint16`` when the file held them as they are, else ``float32``).
    source : Path
    file_format : str
        "PNG", "TIFF", "NPY", "RAW", "PDS3", "VICAR" or "ISIS3".
    stored_shape : tuple of int
        Shape of the array in the file.
    stored_dtype : str
    full_frame : bool
        Binned here from a full frame.
    dn_rule : str
        How stored values became DN, and on whose word (declaration, label or convention).
    """

    dn: np.ndarray
    source: Path
    file_format: str
    stored_shape: tuple
    stored_dtype: str
    full_frame: bool
    dn_rule: str

    def describe(self) -> dict:
        """JSON-ready provenance (no pixels)."""
        return {"file": str(self.source), "format": self.file_format, "stored_shape": list(self.stored_shape),
                "stored_dtype": self.stored_dtype, "binned_from_full_frame": self.full_frame,
                "dn_rule": self.dn_rule}


def accepted_shapes(camera: Any) -> str:
    rows, columns, binning = camera.height_px, camera.width_px, camera.binning_rows
    return (f"{rows // binning} x {columns} (rows binned on chip) or {rows} x {columns} (full frame), grey; "
            f"RGB/RGBA of those sizes with --channel or --luminance")


def read_descent_image(path: str | Path, camera: Any,
                       declaration: ImageDeclaration = ImageDeclaration()) -> DescentImageFile:
    """Read one descent image file as binned camera DN (module docstring for the rules).

    Parameters
    ----------
    path : path-like
    camera : Camera
        Supplies the detector size, on-chip binning, ADC bits, offset, gain and full well.
    declaration : ImageDeclaration

    Raises
    ------
    InputFileError
        One line naming the file and what to add or change.
    """
    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: file not found")
    values, file_format, label_bits = _decode(path, camera, declaration)
    stored_shape, stored_dtype = values.shape, str(values.dtype)
    values = _select_channel(path, values, declaration, camera)
    rows, columns, binning = camera.height_px, camera.width_px, camera.binning_rows
    if values.shape not in ((rows // binning, columns), (rows, columns)):
        raise InputFileError(f"{path}: image shape {_shape_text(stored_shape)}; accepted: {accepted_shapes(camera)}")
    if values.dtype.kind == "f" and not np.isfinite(values).all():
        raise InputFileError(f"{path}: image contains non-finite values")
    stored = np.dtype(stored_dtype)                      # an integer RGB image keeps its depth after luminance
    container_bits = 8 * stored.itemsize if stored.kind in "ui" else None
    dn, saturated, rule = to_camera_dn(path, values, container_bits, label_bits, declaration, camera)
    full_frame = dn.shape[0] == rows and binning > 1
    if full_frame:
        top = check_full_frame_top_bits(path, values, label_bits, declaration, camera)
        saturated = top if saturated is None else (saturated if top is None else saturated | top)
        dn = bin_full_frame(dn, saturated, camera)
        rule += f"; full frame binned {binning}:1 in rows as on chip"
    elif saturated is not None:
        dn = dn.astype(np.float32, copy=True)
        dn[saturated] = camera.electronics.max_dn
    return DescentImageFile(dn=dn, source=path, file_format=file_format, stored_shape=tuple(stored_shape),
                            stored_dtype=stored_dtype, full_frame=full_frame, dn_rule=rule)


def load_image(path: str | Path, camera: Any, declaration: ImageDeclaration = ImageDeclaration()) -> np.ndarray:
    """:func:`read_descent_image`, the binned DN array only."""
    return read_descent_image(path, camera, declaration).dn


def full_frame_pixel_saturation_dn(camera: Any) -> float:
    """DN at which one full-frame (unbinned) pixel saturates: ``min(DN_max, full_well / gain + offset)``
    (1220 DN for MER: the ADC gain is set so that the *binned* sum of 4 pixels fills the 12 bits)."""
    electronics = camera.electronics
    return float(min(electronics.max_dn, electronics.full_well_e / electronics.adc_gain_e_per_dn
                     + electronics.adc_offset_dn))


def check_full_frame_top_bits(path: Path, values: np.ndarray, label_bits: tuple | None,
                              declaration: ImageDeclaration, camera: Any) -> np.ndarray | None:
    """Refuse a full frame whose values cannot be the declared top bits of a full-frame pixel's DN;
    else the mask of its values at the top (saturated), or None when the rule does not apply.

    With ``bits`` below the camera's ``adc_bits`` (``--bits 8`` for MER, x16) and no ``--dn-scale``, a
    value ``v`` is ``DN = 2^(adc_bits - bits) v + dn_offset``. One full-frame pixel reads at most
    :func:`full_frame_pixel_saturation_dn` (1220 DN), so its top 8 bits are at most 76: a larger value
    means the file holds something else (a display stretch or a look-up table of the 0..1220 DN range),
    and reading it as the top bits would call every pixel above 76 saturated. Such a file is refused
    (one line, naming the value, the limit and the ``--dn-scale`` that states the file's DN range).
    A value at the limit (76) covers the saturation level (1216..1231 DN holds 1220) and is taken as
    saturated, as the declared maximum of a binned file is.
    """
    bits, whose = declaration.bits, "--bits"
    if bits is None and label_bits is not None:
        bits, whose = label_bits
    adc_bits = int(camera.electronics.adc_bits)
    if declaration.dn_scale is not None or bits is None or bits >= adc_bits or not values.size:
        return None
    scale = 2.0 ** (adc_bits - bits)
    offset = float(declaration.dn_offset) if declaration.dn_offset is not None else 0.0
    saturation = full_frame_pixel_saturation_dn(camera)
    limit = int(np.floor((saturation - offset) / scale))
    largest = float(values.max())
    if largest > limit:
        span = 2 ** bits - 1
        raise InputFileError(
            f"{path}: full frame at {whose} {bits}: value {largest:g} would be {scale * largest + offset:g} DN, but one "
            f"full-frame pixel saturates at {saturation:g} DN (value {limit} at {whose} {bits}; x{scale:g}), so these "
            f"are not the top {bits} bits of the DN; state the file's DN range with --dn-scale S [--dn-offset O] "
            f"(e.g. --dn-scale {saturation / span:.4g} if 0..{span} spans 0..{saturation:g} DN)")
    return values >= limit


def bin_full_frame(dn: np.ndarray, saturated: np.ndarray | None, camera: Any) -> np.ndarray:
    """Full-frame DN (H, W) -> binned DN (H / b, W) as the camera bins on chip (module docstring)."""
    electronics = camera.electronics
    binning, offset, max_dn = camera.binning_rows, float(electronics.adc_offset_dn), float(electronics.max_dn)
    frame = np.asarray(dn, dtype=np.float32)
    rows, columns = frame.shape
    blocks = (frame - np.float32(offset)).reshape(rows // binning, binning, columns)
    binned = np.minimum(blocks.sum(axis=1) + np.float32(offset), np.float32(max_dn))
    pixel_saturation = full_frame_pixel_saturation_dn(camera)
    hot = frame >= np.float32(pixel_saturation)
    if saturated is not None:
        hot |= saturated
    binned[hot.reshape(rows // binning, binning, columns).any(axis=1)] = np.float32(max_dn)
    return binned.astype(np.float32)


def to_camera_dn(path: Path, values: np.ndarray, container_bits: int | None, label_bits: tuple | None,
                 declaration: ImageDeclaration, camera: Any) -> tuple[np.ndarray, np.ndarray | None, str]:
    """Stored values -> camera DN, the saturated mask (or None) and the rule applied (module docstring)."""
    adc_bits, max_dn = int(camera.electronics.adc_bits), int(camera.electronics.max_dn)
    offset = float(declaration.dn_offset) if declaration.dn_offset is not None else 0.0
    bits, whose = declaration.bits, "--bits"
    if bits is None and label_bits is not None:
        bits, whose = label_bits
    if bits is not None and container_bits is not None and bits > container_bits:
        raise InputFileError(f"{path}: {whose} {bits} does not fit the file's {container_bits}-bit samples; "
                             f"allowed: up to {container_bits}")
    if bits is not None and values.size:
        largest = float(values.max())
        if largest > 2 ** bits - 1:
            raise InputFileError(f"{path}: value {largest:g} exceeds the {bits}-bit range of {whose} {bits} "
                                 f"(0 to {2 ** bits - 1}); declare the right --bits or --dn-scale")
    if declaration.dn_scale is not None:
        scale = float(declaration.dn_scale)
        dn = values.astype(np.float32) * np.float32(scale) + np.float32(offset)
        return dn, None, f"DN = {scale:g} x value + {offset:g} (--dn-scale/--dn-offset)"
    if bits is not None:
        scale = 2.0 ** (adc_bits - bits)
        saturated = values >= 2 ** bits - 1 if container_bits is not None else None
        if scale == 1.0 and offset == 0.0 and values.dtype == np.uint16:
            return values, (saturated if saturated is not None and saturated.any() else None), \
                f"DN = value ({whose} {bits}: the camera's {adc_bits}-bit DN)"
        dn = values.astype(np.float32) * np.float32(scale) + np.float32(offset)
        return dn, saturated, (f"DN = {scale:g} x value + {offset:g} ({whose} {bits}: the top {bits} bits "
                               f"of the camera's {adc_bits}-bit DN)")
    if container_bits == 8:
        raise InputFileError(f"{path}: 8-bit image without a declared bit depth; add --bits 8 (values are the "
                             f"top 8 bits of the camera's {adc_bits}-bit DN) or --dn-scale S [--dn-offset O]")
    if container_bits is not None:
        if values.size and (int(values.max()) > max_dn or int(values.min()) < 0):
            raise InputFileError(f"{path}: values {int(values.min())} to {int(values.max())} are outside the "
                                 f"camera's {adc_bits}-bit DN range (0 to {max_dn}); add --bits 16 if they fill "
                                 f"16 bits, or --dn-scale S [--dn-offset O]")
        if offset != 0.0:
            return (values.astype(np.float32) + np.float32(offset), None,
                    f"DN = value + {offset:g} ({container_bits}-bit container of camera DN, --dn-offset)")
        return values, None, f"DN = value ({container_bits}-bit container of camera DN)"
    if offset != 0.0:
        return values.astype(np.float32) + np.float32(offset), None, f"DN = value + {offset:g} (float DN, --dn-offset)"
    return values, None, "DN = value (float DN)"


# ------------------------------------------------------------------------------------------------
def _shape_text(shape: tuple) -> str:
    return " x ".join(str(n) for n in shape)


def _select_channel(path: Path, values: np.ndarray, declaration: ImageDeclaration, camera: Any) -> np.ndarray:
    if values.ndim == 3 and values.shape[2] == 1:
        values = values[:, :, 0]
    if values.ndim == 2:             # --channel / --luminance concern colour images only
        return values
    if values.ndim != 3 or values.shape[2] not in (3, 4):
        raise InputFileError(f"{path}: image shape {_shape_text(values.shape)}; accepted: {accepted_shapes(camera)}")
    kind = "RGBA" if values.shape[2] == 4 else "RGB"
    if declaration.channel is not None:
        return np.ascontiguousarray(values[:, :, CHANNELS[str(declaration.channel).lower()]])
    if declaration.luminance:
        weights = np.asarray(LUMINANCE_WEIGHTS, dtype=np.float32)
        return values[:, :, :3].astype(np.float32) @ weights
    raise InputFileError(f"{path}: {kind} image ({_shape_text(values.shape)}); choose one channel with "
                         f"--channel r|g|b, or --luminance")


def _decode(path: Path, camera: Any, declaration: ImageDeclaration) -> tuple[np.ndarray, str, tuple | None]:
    """The stored array (RGB order for colour), the format name and label-stated significant bits."""
    with open(path, "rb") as handle:
        head = handle.read(2048)
    if head.startswith(b"\x89PNG\r\n\x1a\n") or head[:4] in (b"II*\x00", b"MM\x00*"):
        return _decode_raster(path, "PNG" if head.startswith(b"\x89PNG") else "TIFF"), \
            ("PNG" if head.startswith(b"\x89PNG") else "TIFF"), None
    if head.startswith(b"\x93NUMPY"):
        try:
            array = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise InputFileError(f"{path}: not a readable .npy array ({exc})") from None
        if array.dtype.kind not in "uif" or array.dtype.kind == "f" and array.dtype.itemsize > 8:
            raise InputFileError(f"{path}: array dtype {array.dtype}; expected unsigned/signed integers or floats")
        return array, "NPY", None
    planetary = read_planetary(path, head, declaration.dn_scale is not None)
    if planetary is not None:
        return planetary
    return _decode_raw(path, camera, declaration), "RAW", None


def _decode_raster(path: Path, kind: str) -> np.ndarray:
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    try:
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    finally:
        cv2.utils.logging.setLogLevel(level)
    if image is None:
        raise InputFileError(f"{path}: not a readable {kind} image")
    if image.ndim == 3 and image.shape[2] in (3, 4):                    # OpenCV gives BGR(A)
        image = cv2.cvtColor(image, cv2.COLOR_BGR2RGB if image.shape[2] == 3 else cv2.COLOR_BGRA2RGBA)
    return image


def _decode_raw(path: Path, camera: Any, declaration: ImageDeclaration) -> np.ndarray:
    rows, columns, binning = camera.height_px, camera.width_px, camera.binning_rows
    sample_bytes = 1 if declaration.bits == 8 else 2
    size = path.stat().st_size
    for shape in ((rows // binning, columns), (rows, columns)):
        if size == shape[0] * shape[1] * sample_bytes:
            if sample_bytes == 1:
                return np.fromfile(path, dtype=np.uint8).reshape(shape)
            dtype = ">u2" if declaration.big_endian else "<u2"
            return np.fromfile(path, dtype=dtype).reshape(shape).astype(np.uint16)
    expected = ", ".join(f"{r * c * sample_bytes} ({r} x {c})" for r, c in ((rows // binning, columns), (rows, columns)))
    kind = "uint8 (--bits 8)" if sample_bytes == 1 else "uint16"
    raise InputFileError(f"{path}: not PNG/TIFF/.npy/PDS3/VICAR/ISIS3, and as raw {kind} samples without a header "
                         f"its {size} bytes match no accepted shape; expected bytes: {expected}")


def write_descent_image(path: str | Path, dn: np.ndarray) -> Path:
    """Write binned camera DN as a 16-bit grey PNG that :func:`read_descent_image` reads back unchanged.

    The 16-bit container holds the DN as they are (no scaling, no stretch), the convention read
    without a declaration; so the estimator gets the same ``uint16`` array from the file as in memory.

    Parameters
    ----------
    path : path-like
        Output file; must end in ``.png``.
    dn : ndarray, (H / b, W) or (H, W), integer values 0..65535
        Camera DN as read out (``uint16`` from the simulator).

    Raises
    ------
    InputFileError
        A non-integer, negative or too large value, a wrong suffix, or a file that cannot be written.
    """
    path = Path(path)
    array = np.asarray(dn)
    if path.suffix.lower() != ".png":
        raise InputFileError(f"{path}: descent images are written as 16-bit PNG; allowed suffix: .png")
    if array.ndim != 2 or array.size == 0:
        raise InputFileError(f"{path}: expected a 2-D DN array; got shape {array.shape}")
    if array.dtype != np.uint16:
        if array.dtype.kind not in "uif" or not np.all(np.isfinite(array)) or np.any(array != np.round(array)) \
                or array.min() < 0 or array.max() > 65535:
            raise InputFileError(f"{path}: DN must be whole numbers 0 to 65535 to be written as 16-bit PNG")
        array = array.astype(np.uint16)
    if not cv2.imwrite(str(path), np.ascontiguousarray(array)):
        raise InputFileError(f"{path}: cannot write PNG")
    return path


def write_preview_png(path: str | Path, dn: np.ndarray, low_dn: float | None = None,
                      high_dn: float | None = None) -> Path:
    """A descent image as an 8-bit grey PNG for people to look at (not for reading back as DN).

    Parameters
    ----------
    path : path-like
        Output file (PNG, whatever its suffix).
    dn : ndarray, (H / b, W)
        Binned camera DN.
    low_dn, high_dn : float, optional
        The stretch: ``low_dn`` -> 0, ``high_dn`` -> 255, clipped (default: the image's 1st and 99th
        percentiles). Rows are repeated 4x to show the 1024x1024 frame's aspect.
    """
    path = Path(path)
    values = np.asarray(dn, dtype=float)
    low = np.percentile(values, 1) if low_dn is None else low_dn
    high = np.percentile(values, 99) if high_dn is None else high_dn
    scaled = np.clip((values - low) / max(high - low, 1e-9), 0, 1)
    # PIL, not cv2.imwrite: a failed write (a full disk) raises OSError with its errno, and libpng prints nothing
    Image.fromarray((255 * np.repeat(scaled, 4, axis=0)).astype(np.uint8)).save(path, format="PNG")
    return path
