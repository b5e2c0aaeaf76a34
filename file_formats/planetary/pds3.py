"""PDS3 image reader: ``.IMG`` with attached or detached (``.LBL``) label, ``IMAGE`` or ``QUBE`` objects.

Hand-written on :mod:`.pvl` (the usual third-party reader fails on two of the project's sample
products). Handled: record and byte pointers (``^IMAGE = 5``, ``^IMAGE = 1155 <BYTES>``,
``^IMAGE = ("F.IMG", 3)``), line prefix/suffix bytes (HiRISE EDR, HRSC), BSQ/BIL/BIP,
``SAMPLE_TYPE``/``SAMPLE_BITS`` with byte order, ``OFFSET``/``SCALING_FACTOR``,
``MISSING_CONSTANT``/``INVALID_CONSTANT``, spectral qubes (``CORE_*`` keywords, THEMIS).

MOC predictive compression (``ENCODING_TYPE = "MOC-PRED-X-5"`` and other ``MOC-PRED-*``, the ``.imq``
products) is decoded through ``pdr`` (its port of the MSSS decompressor); the result is checked against
the label's LINES x LINE_SAMPLES and, in the tests, bit for bit against the MSSS-decompressed product.

Refused with a clear error: other compressed products (``ENCODING_TYPE``: MOC transform compression
``MOC-DCT-*``/``MOC-WHT-*``, which pdr decodes lossily and which no reference here checks, Huffman
first-difference, ...), VAX reals, unknown sample types, qube suffix planes, files shorter than the
label promises.

A pointer that lands inside the attached label itself is impossible; two cropped ISIS test
products (MOC WA, HRSC) have one. When the bytes after the label are exactly the image size,
the data are read from the label end and a note records it; otherwise the file is refused.
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from file_formats.planetary.image import OrbitalImage, fail, file_size, read_attached_label
from file_formats.planetary.layout import RasterLayout, check_dimensions, decode_band
from file_formats.planetary.pvl import Quantity, lookup, to_plain

# SAMPLE_TYPE -> (byte order, numpy kind)
SAMPLE_TYPES = {
    "UNSIGNED_INTEGER": (">", "u"), "MSB_UNSIGNED_INTEGER": (">", "u"), "SUN_UNSIGNED_INTEGER": (">", "u"),
    "MAC_UNSIGNED_INTEGER": (">", "u"), "LSB_UNSIGNED_INTEGER": ("<", "u"), "PC_UNSIGNED_INTEGER": ("<", "u"),
    "VAX_UNSIGNED_INTEGER": ("<", "u"), "INTEGER": (">", "i"), "MSB_INTEGER": (">", "i"),
    "SUN_INTEGER": (">", "i"), "MAC_INTEGER": (">", "i"), "LSB_INTEGER": ("<", "i"), "PC_INTEGER": ("<", "i"),
    "VAX_INTEGER": ("<", "i"), "IEEE_REAL": (">", "f"), "REAL": (">", "f"), "FLOAT": (">", "f"),
    "SUN_REAL": (">", "f"), "MAC_REAL": (">", "f"), "MSB_REAL": (">", "f"), "PC_REAL": ("<", "f"),
    "LSB_REAL": ("<", "f"),
}
_ALLOWED_BITS = {"u": (8, 16, 32), "i": (8, 16, 32), "f": (32, 64)}
_NO_ENCODING = {"N/A", "NONE", "NULL", "UNCOMPRESSED", "UNK"}
_IMAGE_POINTERS = ("^IMAGE", "^SPECTRAL_QUBE", "^QUBE")
_STORAGE = {"BAND_SEQUENTIAL": "BSQ", "LINE_INTERLEAVED": "BIL", "SAMPLE_INTERLEAVED": "BIP"}
_QUBE_AXES: dict[tuple[str, ...], str] = {("SAMPLE", "LINE", "BAND"): "BSQ", ("SAMPLE", "BAND", "LINE"): "BIL",
              ("BAND", "SAMPLE", "LINE"): "BIP"}


def looks_like_pds3(head: bytes) -> bool:
    """True when the first bytes are a PDS3/ODL label (``PDS_VERSION_ID``, ``CCSD``, ``ODL_VERSION_ID``)."""
    text = head[:64].lstrip().upper()
    return text.startswith((b"PDS_VERSION_ID", b"CCSD", b"ODL_VERSION_ID", b"NJPL"))


def read_pds3(path: str | Path, band_index: int = 0) -> OrbitalImage:
    """Read one band of a PDS3 image product.

    Parameters
    ----------
    path : path-like
        The ``.IMG``/``.QUB`` file (attached label), its detached ``.LBL``, or a data file whose
        detached label sits beside it with the same stem.
    band_index : int
        0-based band of multi-band products.

    Returns
    -------
    OrbitalImage
    """
    path = Path(path)
    label_path = _label_path(path)
    parsed, _ = read_attached_label(label_path, "PDS3")
    tree = parsed.tree
    pointer_key = next((key for key in _IMAGE_POINTERS if lookup(tree, key) is not None), None)
    if pointer_key is None:
        pointers = [key for key in tree if key.startswith("^")]
        raise fail(label_path, f"no ^IMAGE or ^SPECTRAL_QUBE/^QUBE pointer in the label (pointers found: "
                               f"{', '.join(pointers) or 'none'})")
    object_name = pointer_key[1:]
    image_object = lookup(tree, object_name)
    if not isinstance(image_object, dict):
        raise fail(label_path, f"{pointer_key} has no matching OBJECT = {object_name} in the label")
    encoding = _encoding(tree, image_object)
    if encoding is not None and encoding.upper().startswith(MOC_PREDICTIVE_PREFIX) and object_name == "IMAGE":
        return _read_moc_predictive(label_path, tree, image_object, encoding, band_index)
    _refuse_encoding(label_path, tree, image_object)
    if object_name == "IMAGE":
        layout = _image_layout(label_path, tree, image_object)
    else:
        layout = _qube_layout(label_path, image_object)
    data_path, offset = _resolve_pointer(label_path, tree, pointer_key, default_data=path)
    notes: list[str] = []
    if data_path == label_path and offset < parsed.end_offset:
        remaining = file_size(data_path) - parsed.end_offset
        if remaining != layout.total_bytes:
            raise fail(label_path, f"{pointer_key} points to byte {offset}, inside the label (which ends at byte "
                                   f"{parsed.end_offset}), and the {remaining} bytes after the label do not match "
                                   f"the {layout.total_bytes} bytes the image needs")
        notes.append(f"{pointer_key} pointed to byte {offset}, inside the label; read the image from the label "
                     f"end (byte {parsed.end_offset}), where exactly {layout.total_bytes} bytes remain")
        offset = parsed.end_offset
    pixels, valid = decode_band(data_path, offset, layout, band_index, f"{object_name} object")
    scale, if_offset = _dn_to_if(tree)
    incidence, emission, phase = _photometric_angles(tree)
    return OrbitalImage(
        pixels=pixels, valid=valid, source=data_path, file_format="PDS3", label=to_plain(tree),
        metres_per_pixel=_map_scale_m(label_path, tree), incidence_rad=incidence, emission_rad=emission,
        phase_rad=phase, dn_to_if_scale=scale, dn_to_if_offset=if_offset, band_index=band_index,
        band_count=layout.bands, notes=tuple(notes))


def _label_path(path: Path) -> Path:
    size = file_size(path)
    with path.open("rb") as handle:
        head = handle.read(min(size, 256))
    if looks_like_pds3(head):
        return path
    for suffix in (".LBL", ".lbl", ".Lbl"):
        candidate = path.with_suffix(suffix)
        if candidate.exists():
            return candidate
    raise fail(path, "no PDS3 label: the file does not start with PDS_VERSION_ID and no detached "
                     f"{path.stem}.LBL / .lbl label is beside it")


MOC_PREDICTIVE_PREFIX = "MOC-PRED-"


def _encoding(tree: dict, image_object: dict) -> str | None:
    for scope in (image_object, tree):
        encoding = lookup(scope, "ENCODING_TYPE")
        if encoding is not None and str(encoding).upper() not in _NO_ENCODING:
            return str(encoding)
    return None


def _read_moc_predictive(path: Path, tree: dict, image_object: dict, encoding: str, band_index: int) -> OrbitalImage:
    """A MOC predictively compressed product decoded by pdr, checked against the label's dimensions."""
    if band_index != 0:
        raise fail(path, f"band_index {band_index} is out of range; a MOC image has 1 band")
    try:   # pdr is heavy (it loads astropy, pandas ...): imported only for MOC-compressed products
        import pdr
    except ImportError:
        raise fail(path, f"ENCODING_TYPE = {encoding!r} needs the pdr package to decode (pip install pdr)") from None
    try:
        pixels = np.asarray(pdr.read(str(path))["IMAGE"])
    except Exception as exc:   # pdr raises many kinds on damaged fragments; report one line
        raise fail(path, f"ENCODING_TYPE = {encoding!r}: pdr could not decode the image "
                         f"({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})") from None
    lines, samples = _integer(path, image_object, "LINES"), _integer(path, image_object, "LINE_SAMPLES")
    if pixels.shape != (lines, samples) or pixels.dtype != np.uint8:
        raise fail(path, f"ENCODING_TYPE = {encoding!r}: pdr decoded {pixels.shape} {pixels.dtype}, the label says "
                         f"LINES = {lines}, LINE_SAMPLES = {samples} of 8-bit samples")
    scale, if_offset = _dn_to_if(tree)
    incidence, emission, phase = _photometric_angles(tree)
    return OrbitalImage(
        pixels=pixels.astype(np.float32), valid=np.ones(pixels.shape, dtype=bool), source=path, file_format="PDS3",
        label=to_plain(tree), metres_per_pixel=_map_scale_m(path, tree), incidence_rad=incidence,
        emission_rad=emission, phase_rad=phase, dn_to_if_scale=scale, dn_to_if_offset=if_offset, band_index=0,
        band_count=1, notes=(f"ENCODING_TYPE = {encoding!r} decoded with pdr {pdr.__version__}",))


def _refuse_encoding(path: Path, tree: dict, image_object: dict) -> None:
    for scope in (image_object, tree):
        encoding = lookup(scope, "ENCODING_TYPE")
        if encoding is not None and str(encoding).upper() not in _NO_ENCODING:
            hint = ""
            if str(encoding).upper().startswith("MOC-"):
                hint = " (MOC transform compression: decompress with the MSSS MOC decompressor first)"
            raise fail(path, f"compressed product: ENCODING_TYPE = {encoding!r}{hint}; only uncompressed "
                             f"images can be read")


def _integer(path: Path, scope: dict, key: str, default: Any = None) -> int:
    value = lookup(scope, key, default=default)
    if isinstance(value, Quantity):
        value = value.value
    if value is None:
        raise fail(path, f"keyword {key} is missing")
    if isinstance(value, bool) or not isinstance(value, int):
        raise fail(path, f"{key} = {value!r} is not an integer")
    return value


def _number(path: Path, scope: dict, key: str, default: float) -> float:
    value = lookup(scope, key, default=default)
    if isinstance(value, Quantity):
        value = value.value
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise fail(path, f"{key} = {value!r} is not a finite number")
    return float(value)


def _dtype(path: Path, type_key: str, type_name: Any, bits_key: str, bits: int) -> np.dtype:
    order_kind = SAMPLE_TYPES.get(str(type_name).upper())
    if order_kind is None:
        if str(type_name).upper().startswith("VAX"):
            raise fail(path, f"{type_key} = {type_name} (VAX floating point) is not supported")
        raise fail(path, f"{type_key} = {type_name!r} is not a known sample type; allowed: "
                         f"{', '.join(sorted(SAMPLE_TYPES))}")
    order, kind = order_kind
    if bits not in _ALLOWED_BITS[kind]:
        raise fail(path, f"{bits_key} = {bits} is not valid for {type_key} = {type_name}; allowed: "
                         f"{', '.join(map(str, _ALLOWED_BITS[kind]))}")
    return np.dtype(f"{'|' if bits == 8 else order}{kind}{bits // 8}")


def _image_layout(path: Path, tree: dict, obj: dict) -> RasterLayout:
    lines, samples = _integer(path, obj, "LINES"), _integer(path, obj, "LINE_SAMPLES")
    bands = _integer(path, obj, "BANDS", default=1)
    check_dimensions(path, lines, samples, bands, ("LINES", "LINE_SAMPLES", "BANDS"))
    sample_type = lookup(obj, "SAMPLE_TYPE")
    if sample_type is None:
        raise fail(path, "keyword SAMPLE_TYPE is missing from the IMAGE object")
    dtype = _dtype(path, "SAMPLE_TYPE", sample_type, "SAMPLE_BITS", _integer(path, obj, "SAMPLE_BITS"))
    storage_name = str(lookup(obj, "BAND_STORAGE_TYPE", default="BAND_SEQUENTIAL")).upper()
    if bands > 1 and storage_name not in _STORAGE:
        raise fail(path, f"BAND_STORAGE_TYPE = {storage_name} is not supported; allowed: {', '.join(_STORAGE)}")
    invalid = []
    for key in ("MISSING_CONSTANT", "MISSING", "INVALID_CONSTANT", "NULL"):
        value = lookup(obj, key)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            invalid.append(_reinterpret_constant(value, dtype))
    prefix = _integer(path, obj, "LINE_PREFIX_BYTES", default=0)
    suffix = _integer(path, obj, "LINE_SUFFIX_BYTES", default=0)
    if prefix < 0 or suffix < 0:
        raise fail(path, f"LINE_PREFIX_BYTES/LINE_SUFFIX_BYTES must be >= 0; got {prefix}/{suffix}")
    return RasterLayout(lines, samples, bands, dtype, _STORAGE.get(storage_name, "BSQ"), prefix, suffix,
                        base=_number(path, obj, "OFFSET", 0.0),
                        multiplier=_number(path, obj, "SCALING_FACTOR", 1.0), invalid_raw=tuple(invalid))


def _reinterpret_constant(value: float, dtype: np.dtype) -> float:
    """A MISSING_CONSTANT written as an unsigned bit pattern (16#FF7FFFFB#) for a float/int type."""
    if dtype.kind == "f" and isinstance(value, int) and value > 2 ** 24:
        return float(np.array([value], dtype=f"u{dtype.itemsize}").view(f"f{dtype.itemsize}")[0])
    if dtype.kind == "i" and isinstance(value, int) and value >= 2 ** (8 * dtype.itemsize - 1):
        return float(value - 2 ** (8 * dtype.itemsize))
    return float(value)


def _qube_layout(path: Path, obj: dict) -> RasterLayout:
    axes = lookup(obj, "AXIS_NAME")
    items = lookup(obj, "CORE_ITEMS")
    if not isinstance(axes, list) or not isinstance(items, list) or len(axes) != 3 or len(items) != 3:
        raise fail(path, f"QUBE needs 3 AXIS_NAME and CORE_ITEMS entries; got {axes!r} and {items!r}")
    storage = _QUBE_AXES.get(tuple(str(a).upper() for a in axes))
    if storage is None:
        raise fail(path, f"AXIS_NAME = {axes} is not supported; allowed orders: "
                         f"{', '.join('(' + ', '.join(k) + ')' for k in _QUBE_AXES)}")
    sizes = {str(a).upper(): n for a, n in zip(axes, items)}
    suffix = lookup(obj, "SUFFIX_ITEMS", default=[0, 0, 0])
    if isinstance(suffix, list) and any(n != 0 for n in suffix):
        raise fail(path, f"QUBE with SUFFIX_ITEMS = {suffix} (backplanes) is not supported")
    check_dimensions(path, sizes["LINE"], sizes["SAMPLE"], sizes["BAND"], ("CORE_ITEMS[LINE]",
                     "CORE_ITEMS[SAMPLE]", "CORE_ITEMS[BAND]"))
    item_bytes = _integer(path, obj, "CORE_ITEM_BYTES")
    dtype = _dtype(path, "CORE_ITEM_TYPE", lookup(obj, "CORE_ITEM_TYPE"), "CORE_ITEM_BYTES*8", 8 * item_bytes)
    specials = [lookup(obj, key) for key in ("CORE_NULL", "CORE_LOW_REPR_SATURATION", "CORE_LOW_INSTR_SATURATION",
                                             "CORE_HIGH_INSTR_SATURATION", "CORE_HIGH_REPR_SATURATION")]
    invalid = tuple(_reinterpret_constant(v, dtype) for v in specials
                    if isinstance(v, (int, float)) and not isinstance(v, bool))
    valid_min = lookup(obj, "CORE_VALID_MINIMUM")
    valid_min = _reinterpret_constant(valid_min, dtype) if isinstance(valid_min, (int, float)) else None
    return RasterLayout(sizes["LINE"], sizes["SAMPLE"], sizes["BAND"], dtype, storage,
                        base=_number(path, obj, "CORE_BASE", 0.0),
                        multiplier=_number(path, obj, "CORE_MULTIPLIER", 1.0),
                        invalid_raw=invalid, valid_raw_min=valid_min)


def _resolve_pointer(label_path: Path, tree: dict, key: str, default_data: Path) -> tuple[Path, int]:
    """(data file, 0-based byte offset) of a pointer.

    A pointer without a file name refers to the label's own file, except when the label is a detached
    ``.LBL`` found beside the data file the caller named: then it refers to that data file.
    """
    value = lookup(tree, key)
    file_name, location = None, None
    if isinstance(value, list):
        if not value or not isinstance(value[0], str):
            raise fail(label_path, f"{key} = {value!r} is not a valid pointer")
        file_name = value[0]
        location = value[1] if len(value) > 1 else 1
    elif isinstance(value, str):
        file_name, location = value, 1
    else:
        location = value
    if isinstance(location, Quantity):
        if location.unit.upper() != "BYTES" or not isinstance(location.value, int):
            raise fail(label_path, f"{key} = {location.value} <{location.unit}>: only <BYTES> units are allowed")
        offset = location.value - 1
    elif isinstance(location, int) and not isinstance(location, bool):
        record_bytes = lookup(tree, "RECORD_BYTES")
        if isinstance(record_bytes, Quantity):
            record_bytes = record_bytes.value
        if location == 1:
            offset = 0
        elif not isinstance(record_bytes, int) or record_bytes <= 0:
            raise fail(label_path, f"{key} = {location} is a record number but RECORD_BYTES = {record_bytes!r} "
                                   f"is not a positive integer")
        else:
            offset = (location - 1) * record_bytes
    else:
        raise fail(label_path, f"{key} = {value!r} is not a valid pointer (record number, <BYTES> or file name)")
    if offset < 0:
        raise fail(label_path, f"{key} = {value!r} points before the start of the file")
    if file_name is not None:
        data_path = _sibling(label_path, file_name, key)
    else:
        data_path = default_data if default_data != label_path and default_data.suffix.lower() != ".lbl" else label_path
    return data_path, offset


def _sibling(label_path: Path, name: str, key: str) -> Path:
    candidate = label_path.parent / name
    if candidate.exists():
        return candidate
    for entry in label_path.parent.iterdir():
        if entry.name.lower() == name.lower():
            return entry
    raise fail(label_path, f"{key} names data file {name!r}, which is not in {label_path.parent}")


def _find_key(tree: Any, name: str) -> Any:
    """Depth-first search for a keyword anywhere in the label."""
    if isinstance(tree, dict):
        found = lookup(tree, name)
        if found is not None:
            return found
        for value in tree.values():
            if isinstance(value, (dict, list)):
                found = _find_key(value, name)
                if found is not None:
                    return found
    elif isinstance(tree, list):
        for value in tree:
            found = _find_key(value, name)
            if found is not None:
                return found
    return None


_LENGTH_UNITS_M = {"KM/PIXEL": 1000.0, "KM/PIX": 1000.0, "M/PIXEL": 1.0, "METERS/PIXEL": 1.0,
                   "METRES/PIXEL": 1.0, "M/PIX": 1.0, "METERS/PIX": 1.0}


def _map_scale_m(path: Path, tree: dict) -> float | None:
    """MAP_SCALE of an IMAGE_MAP_PROJECTION object, in metres per pixel, or None."""
    projection = _find_key(tree, "IMAGE_MAP_PROJECTION")
    if not isinstance(projection, dict):
        return None
    scale = lookup(projection, "MAP_SCALE")
    if isinstance(scale, Quantity):
        factor = _LENGTH_UNITS_M.get(re.sub(r"\s+", "", scale.unit.upper()))
        if factor is None:
            raise fail(path, f"MAP_SCALE unit <{scale.unit}> is not understood; allowed: "
                             f"{', '.join(sorted(_LENGTH_UNITS_M))}")
        value = scale.value * factor
    elif isinstance(scale, (int, float)) and not isinstance(scale, bool):
        value = scale * 1000.0  # PDS3 default unit of MAP_SCALE is KM/PIXEL
    else:
        return None
    return float(value) if value > 0 and math.isfinite(value) else None


def _photometric_angles(tree: dict) -> tuple[float | None, float | None, float | None]:
    angles = []
    for key, upper in (("INCIDENCE_ANGLE", 90.0), ("EMISSION_ANGLE", 90.0), ("PHASE_ANGLE", 180.0)):
        value = _find_key(tree, key)
        if isinstance(value, Quantity):
            value = value.value if value.unit.upper().startswith("DEG") else None
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and 0.0 <= value <= upper
        angles.append(math.radians(value) if ok else None)
    return angles[0], angles[1], angles[2]


def _dn_to_if(tree: dict) -> tuple[float | None, float | None]:
    """DN-to-I/F factors stated by the label (HRSC level 2 REFLECTANCE_SCALING_FACTOR), else None."""
    factor = lookup(tree, "REFLECTANCE_SCALING_FACTOR")
    if isinstance(factor, Quantity):
        factor = factor.value
    if isinstance(factor, (int, float)) and not isinstance(factor, bool) and factor > 0:
        return float(factor), 0.0
    return None, None

