"""``[scene.relief]``, the relief render's switches (simulator.scene.relief re-exports the class).

A table of its own, so that declaring a configuration loads no render code: the parallax method's compiled
passes (numba, which imports scipy) are loaded by a relief render.
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field

from config_tables.models import ConfigModel


class ReliefConfig(ConfigModel):
    """``[scene.relief]``: how a terrain's height field is rendered.

    Terrains without one are unaffected; a class gets one with ``relief = true`` in its terrain table).
    """

    enabled: bool = True
    """Render the height field of terrains that have one (off: level ground, as a plain terrain)."""
    method: Literal["parallax", "march"] = "parallax"
    """``parallax``: fixed-point parallax iterations, shading baked on the grid, the march only where a
    nearer bump may occlude (simulator.scene.parallax); ``march``: every ray marched, shading per point
    (the reference)."""
    march_step_terrain_px: float = Field(0.5, ge=0.05, le=2.0)
    """Largest horizontal move of a ray (and of a sun ray) per march step, in terrain pixels."""
    height_tolerance_m: float = Field(1.0e-3, ge=1.0e-6, le=0.1)
    """The refined hit point is within this height of the surface (m)."""
    slope_photometry: bool = True
    """Shade each point with the photometric function at its local normal."""
    cast_shadows: bool = True
    """Relief casts shadows (sun rays marched over the height field)."""
    shadow_edge_m: float = Field(0.05, ge=0.0, le=10.0)
    """Height band over which a point goes from shadow to light (penumbra, m)."""
