"""Format dispatch and real-image terrain: ``read_image`` and ``load_terrain``.

The format is recognised from the file's first bytes, not its extension: ISIS3 (``Object =
IsisCube``), PDS3 (``PDS_VERSION_ID``/``CCSD``/``ODL_VERSION_ID``, or a detached ``.LBL`` beside
a data file), VICAR (``LBLSIZE=``), MSSS DDD (magic 1659), PNG and TIFF/GeoTIFF signatures.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from .image import OrbitalImage, fail, file_size
from .isis3 import looks_like_isis3, read_isis3
from .pds3 import looks_like_pds3, read_pds3
from .raster import looks_like_raster, read_raster
from .sidecar import Sidecar, apply_sidecar, default_sidecar_path, read_sidecar, refuse_unknown
from .vicar import looks_like_ddd, looks_like_vicar, read_ddd, read_vicar

if TYPE_CHECKING:  # the simulator is imported only when a terrain is built (the estimator reads
    from simulator.scene.terrain import Terrain   # descent images through these readers without it)

SUPPORTED_FORMATS = "PDS3 (.IMG/.LBL/.QUB), ISIS3 (.cub), VICAR, MSSS DDD, PNG, TIFF/GeoTIFF"
# A negative I/F after calibration on more than this fraction of valid pixels means a wrong offset.
MAX_NEGATIVE_IF_FRACTION = 0.01


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


def load_terrain(path: str | Path, sidecar: str | Path | Sidecar | None = None, *,
                 min_valid_fraction: float = 0.5) -> "Terrain":
    """A :class:`simulator.scene.terrain.Terrain` from a real orbital image file.

    Parameters
    ----------
    path : path-like
        Image file (any format of :func:`read_image`).
    sidecar : path-like, Sidecar or None
        Side-car TOML; None looks for ``<stem>.toml`` beside the image.
    min_valid_fraction : float
        Refuse images (after cropping) with fewer valid pixels than this fraction.

    Returns
    -------
    Terrain
        Reflectance (I/F, float32, >= 0, finite) on a grid whose centre is at world (0, 0); rows
        are taken as running north to south. Invalid pixels take the value of the nearest valid one.

    Raises
    ------
    ReaderError
        Unreadable file, or metres per pixel, photometric angles or DN-to-I/F still unknown after the
        side-car, or too few valid pixels, or a calibration giving negative I/F.
    ConfigError
        Bad side-car field.
    """
    resolved = resolve_sidecar(path, sidecar)
    image = load_orbital_image(path, resolved)
    hint = f"{default_sidecar_path(path).name} beside the image, or sidecar=..."
    if image.metres_per_pixel is None:
        refuse_unknown(image, "metres per pixel", "metres_per_pixel", hint)
    for field in ("incidence", "emission", "phase"):
        if getattr(image, f"{field}_rad") is None:
            refuse_unknown(image, f"the orbital observation's {field} angle", f"{field}_deg", hint)
    if image.dn_to_if_scale is None:
        refuse_unknown(image, "the DN-to-I/F calibration", "dn_to_if_scale (and dn_to_if_offset)", hint)
    valid_fraction = float(image.valid.mean())
    if valid_fraction < min_valid_fraction:
        raise fail(image.source, f"only {100 * valid_fraction:.1f} % of the pixels are valid (minimum "
                                 f"{100 * min_valid_fraction:.0f} %); choose a [crop] window in the side-car")
    offset = image.dn_to_if_offset if image.dn_to_if_offset is not None else 0.0
    reflectance = image.pixels.astype(np.float64) * image.dn_to_if_scale + offset
    negative = (reflectance < 0) & image.valid
    if negative.mean() > MAX_NEGATIVE_IF_FRACTION * valid_fraction:
        raise fail(image.source, f"dn_to_if_scale/offset give negative I/F on {100 * negative.mean():.1f} % of the "
                                 f"pixels (allowed up to {100 * MAX_NEGATIVE_IF_FRACTION:.0f} %); check the offset")
    reflectance = np.clip(reflectance, 0.0, None)
    if not image.valid.all():
        nearest = ndimage.distance_transform_edt(~image.valid, return_distances=False, return_indices=True)
        reflectance = reflectance[tuple(nearest)]
    rows, cols = image.shape
    metres = float(image.metres_per_pixel)
    origin = np.array([-(cols - 1) / 2 * metres, (rows - 1) / 2 * metres])
    name = resolved.name if resolved is not None and resolved.name else Path(path).stem
    from simulator.scene.terrain import Terrain

    return Terrain(reflectance_if=reflectance.astype(np.float32), metres_per_pixel=metres, origin_m=origin,
                   moc_incidence_rad=float(image.incidence_rad), moc_emission_rad=float(image.emission_rad),
                   moc_phase_rad=float(image.phase_rad), name=name)
