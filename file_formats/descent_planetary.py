"""PDS3, VICAR and ISIS3 descent images through the :mod:`file_formats.planetary` label parsers.

Only the format readers are imported (``file_formats.planetary.pds3``, ``.vicar``, ``.isis3``); they need
no simulator module. The readers return float32 pixels after the label's own scaling and a validity
mask; here the stored sample type is recovered from the label so that the bit-depth rules of
:mod:`file_formats.descent_images` apply exactly as to a PNG of the same type:

* integer samples with no label scaling come back as integers (``uint8``, ``uint16``, or ``int32``
  for signed or 32-bit samples); special pixels (missing, NULL, ISIS special values) become 0 DN,
  which the estimator treats as "no signal";
* the significant bits are read from a ``SAMPLE_BIT_MASK`` (PDS3 image object, or a VICAR label
  keyword) of contiguous low bits wider than 8 bits (``2#0000111111111111#`` -> 12); an 8-bit mask is not taken as a DN scale (MER 8-bit
  products are companded through a look-up table), so 8-bit samples still need a declaration;
* a label scaling (PDS3 ``OFFSET``/``SCALING_FACTOR``, ISIS3 ``Base``/``Multiplier``) or float
  samples mean the values are not raw DN: they are refused unless ``--dn-scale`` states the DN;
* multi-band products are refused (a descent image has one band).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from file_formats.errors import InputFileError
from file_formats.planetary.image import ReaderError
from file_formats.planetary.isis3 import looks_like_isis3, read_isis3
from file_formats.planetary.pds3 import looks_like_pds3, read_pds3
from file_formats.planetary.vicar import looks_like_vicar, read_vicar


def read_planetary(path: Path, head: bytes, dn_scale_declared: bool) -> tuple[np.ndarray, str, tuple | None] | None:
    """(stored values, format name, (significant bits, source) or None), or None when ``path`` is
    neither PDS3, VICAR nor ISIS3. Raises :class:`~file_formats.errors.InputFileError`."""
    detached = path.suffix.lower() == ".lbl" or any(path.with_suffix(s).exists() for s in (".LBL", ".lbl"))
    if looks_like_isis3(head):
        reader, kind = read_isis3, "ISIS3"
    elif looks_like_pds3(head) or detached:
        reader, kind = read_pds3, "PDS3"
    elif looks_like_vicar(head):
        reader, kind = read_vicar, "VICAR"
    else:
        return None
    try:
        image = reader(path)
    except ReaderError as exc:
        raise InputFileError(str(exc)) from None
    if image.band_count != 1:
        raise InputFileError(f"{path}: {kind} product has {image.band_count} bands; a descent image has one")
    dtype, scaled, bits = _stored_type(kind, image.label)
    values = image.pixels
    if scaled or dtype is None:
        if not dn_scale_declared:
            what = "scaled samples (label offset/multiplier)" if scaled else "float samples"
            raise InputFileError(f"{path}: {kind} product with {what} is not raw camera DN; "
                                 f"add --dn-scale S [--dn-offset O] to state how its values become DN")
        return values, kind, None
    integers = np.rint(values).astype(np.int64)
    if dtype == np.uint8 or (dtype == np.uint16 and integers.min(initial=0) >= 0):
        integers = integers.astype(dtype)
    else:
        integers = integers.astype(np.int32)
    return integers, kind, bits


def _stored_type(kind: str, label: dict) -> tuple[type | None, bool, tuple | None]:
    """(integer dtype or None for float samples, label scaling present, label significant bits)."""
    if kind == "PDS3":
        image = label.get("IMAGE", {}) if isinstance(label.get("IMAGE"), dict) else {}
        sample_type = str(image.get("SAMPLE_TYPE", "")).upper()
        sample_bits = int(image.get("SAMPLE_BITS", 0) or 0)
        scaled = float(image.get("OFFSET", 0.0) or 0.0) != 0.0 or float(image.get("SCALING_FACTOR", 1.0) or 1.0) != 1.0
        if "REAL" in sample_type or "FLOAT" in sample_type:
            return None, scaled, None
        bits = _mask_bits(image.get("SAMPLE_BIT_MASK"), sample_bits)
        dtype = np.uint8 if sample_bits == 8 and "UNSIGNED" in sample_type else \
            np.uint16 if sample_bits == 16 else np.int32
        return dtype, scaled, bits
    if kind == "VICAR":
        name = str(label.get("FORMAT", "")).upper()
        if name in ("REAL", "DOUB"):
            return None, False, None
        sample_bits = {"BYTE": 8, "HALF": 16, "WORD": 16}.get(name, 32)
        mask = label.get("SAMPLE_BIT_MASK")
        if mask is None:                      # property and history labels keep their keywords in order
            mask = next((value for key, value in label.get("_HISTORY", []) if key == "SAMPLE_BIT_MASK"), None)
        return {8: np.uint8, 16: np.uint16}.get(sample_bits, np.int32), False, _mask_bits(mask, sample_bits)
    cube = label.get("IsisCube", {})
    pixels = cube.get("Core", {}).get("Pixels", {}) if isinstance(cube, dict) else {}
    type_name = str(pixels.get("Type", "")).upper()
    if type_name == "REAL":
        return None, False, None
    scaled = float(pixels.get("Base", 0.0) or 0.0) != 0.0 or float(pixels.get("Multiplier", 1.0) or 1.0) != 1.0
    return {"UNSIGNEDBYTE": np.uint8, "UNSIGNEDWORD": np.uint16}.get(type_name, np.uint16), scaled, None


def _mask_bits(mask, sample_bits: int) -> tuple | None:
    """(significant bits, source) from a ``SAMPLE_BIT_MASK`` of contiguous low bits wider than 8 and
    no wider than the samples (an integer, or PDS/VICAR radix text such as ``2#0000111111111111#``)."""
    if isinstance(mask, str):
        text = mask.strip().strip("'\"")
        try:
            base, digits = text.rstrip("#").split("#", 1)
            mask = int(digits, int(base))
        except ValueError:
            return None
    if isinstance(mask, bool) or not isinstance(mask, int) or mask <= 0 or (mask & (mask + 1)) != 0:
        return None
    width = mask.bit_length()
    return (width, "label SAMPLE_BIT_MASK") if 8 < width <= sample_bits else None
