"""Format dispatch of orbital image files: ``detect_format``, ``read_image``, ``load_orbital_image``.

The format is recognised from the file's first bytes, not its extension: ISIS3 (``Object =
IsisCube``), PDS3 (``PDS_VERSION_ID``/``CCSD``/``ODL_VERSION_ID``, or a detached ``.LBL`` beside
a data file), VICAR (``LBLSIZE=``), MSSS DDD (magic 1659), PNG and TIFF/GeoTIFF signatures.
"""
from __future__ import annotations

from pathlib import Path

from file_formats.planetary.image import OrbitalImage, fail, file_size
from file_formats.planetary.isis3 import looks_like_isis3, read_isis3
from file_formats.planetary.pds3 import looks_like_pds3, read_pds3
from file_formats.planetary.raster import looks_like_raster, read_raster
from file_formats.planetary.sidecar import Sidecar, apply_sidecar, default_sidecar_path, read_sidecar
from file_formats.planetary.vicar import looks_like_ddd, looks_like_vicar, read_ddd, read_vicar

SUPPORTED_FORMATS = "PDS3 (.IMG/.LBL/.QUB), ISIS3 (.cub), VICAR, MSSS DDD, PNG, TIFF/GeoTIFF"


def detect_format(path: str | Path) -> str:
    """"ISIS3", "PDS3", "VICAR", "DDD" or "RASTER" from the file's first bytes (ReaderError otherwise)."""
    path = Path(path)
    size = file_size(path)
    with path.open("rb") as handle:
        head = handle.read(min(size, 256))
    if looks_like_isis3(head):
        return "ISIS3"
    if looks_like_pds3(head) or path.suffix.lower() == ".lbl":
        return "PDS3"
    if looks_like_vicar(head):
        return "VICAR"
    if looks_like_raster(head):
        return "RASTER"
    if looks_like_ddd(head):
        return "DDD"
    if any(path.with_suffix(s).exists() for s in (".LBL", ".lbl")):
        return "PDS3"
    raise fail(path, f"unrecognised image format (first bytes {head[:16]!r}); supported: {SUPPORTED_FORMATS}")


def read_image(path: str | Path, band_index: int = 0) -> OrbitalImage:
    """Read one band of any supported orbital image file."""
    path = Path(path)
    kind = detect_format(path)
    if kind == "ISIS3":
        return read_isis3(path, band_index)
    if kind == "PDS3":
        return read_pds3(path, band_index)
    if kind == "VICAR":
        return read_vicar(path, band_index)
    if kind == "RASTER":
        return read_raster(path, band_index)
    if band_index != 0:
        raise fail(path, f"band_index {band_index} is out of range; a DDD file has 1 band")
    return read_ddd(path)


def resolve_sidecar(image_path: str | Path, sidecar: str | Path | Sidecar | None) -> Sidecar | None:
    """The side-car for an image: the one given, else ``<stem>.toml`` beside the image if it exists."""
    if isinstance(sidecar, Sidecar):
        return sidecar
    if sidecar is not None:
        return read_sidecar(sidecar)
    candidate = default_sidecar_path(image_path)
    return read_sidecar(candidate) if candidate.exists() else None


def load_orbital_image(path: str | Path, sidecar: str | Path | Sidecar | None = None) -> OrbitalImage:
    """Read an image and apply its side-car (band choice, crop, scale, angles, calibration)."""
    resolved = resolve_sidecar(path, sidecar)
    band_index = resolved.band_index if resolved is not None and resolved.band_index is not None else 0
    return apply_sidecar(read_image(path, band_index), resolved)
