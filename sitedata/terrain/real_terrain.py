"""Real-image terrain: an orbital image file and its side-car -> a simulator :class:`Terrain`.

The file is read by :mod:`file_formats.planetary`; what it lacks (metres per pixel, photometric
angles, DN-to-I/F) comes from the side-car TOML, and nothing is guessed.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from file_formats.planetary.image import fail
from file_formats.planetary.orbital_file import load_orbital_image, resolve_sidecar
from file_formats.planetary.sidecar import Sidecar, default_sidecar_path, refuse_unknown
from simulator.scene.terrain import Terrain

# A negative I/F after calibration on more than this fraction of valid pixels means a wrong offset.
MAX_NEGATIVE_IF_FRACTION = 0.01


def load_terrain(path: str | Path, sidecar: str | Path | Sidecar | None = None, *,
                 min_valid_fraction: float = 0.5) -> Terrain:
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
    from scipy import ndimage

    resolved = resolve_sidecar(path, sidecar)
    image = load_orbital_image(path, resolved)
    hint = f"{default_sidecar_path(path).name} beside the image, or sidecar=..."
    if image.metres_per_pixel is None:
        refuse_unknown(image, "metres per pixel", "metres_per_pixel", hint)
    if image.incidence_rad is None:
        refuse_unknown(image, "the orbital observation's incidence angle", "incidence_deg", hint)
    if image.emission_rad is None:
        refuse_unknown(image, "the orbital observation's emission angle", "emission_deg", hint)
    if image.phase_rad is None:
        refuse_unknown(image, "the orbital observation's phase angle", "phase_deg", hint)
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
    return Terrain(reflectance_if=reflectance.astype(np.float32), metres_per_pixel=metres, origin_m=origin,
                   moc_incidence_rad=float(image.incidence_rad), moc_emission_rad=float(image.emission_rad),
                   moc_phase_rad=float(image.phase_rad), name=name)
