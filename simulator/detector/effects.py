"""The camera chain's switches, ``[scene.camera_effects]``.

A configuration table of their own, so that declaring a configuration (campaign.configuration.schemas) loads
no numerical stack: the chain's compiled passes (numba, which imports scipy) are loaded by the chain itself
(simulator.detector.camera_chain re-exports this class).
"""
from __future__ import annotations

from pydantic import Field

from config_tables.models import ConfigModel


class CameraEffects(ConfigModel):
    """``[scene.camera_effects]``: switches of the camera chain; all on is the nominal camera."""

    optics_psf: bool = True
    """The optics' point-spread function (the camera's [optics]; simulator.detector.psf)."""
    falloff: bool = True
    """cos^4 falloff with field angle."""
    prnu: bool = True
    """Pixel response non-uniformity."""
    dark_current: bool = True
    """Dark current (image and storage areas)."""
    dark_current_scale: float = Field(1.0, ge=0.0, le=1e6)
    """Multiplies the camera's dark current (excessive dark current: > 1)."""
    smear: bool = True
    """Fast-flush and frame-transfer smear."""
    shot_noise: bool = True
    """Photon and dark shot noise."""
    read_noise: bool = True
    """Output amplifier noise."""
    exact_poisson: bool = False
    """Poisson shot noise at every level (false: Gaussian above readout.GAUSSIAN_MIN_MEAN_E, a fidelity shortcut)."""
