"""Fidelity presets: named sets of the documented shortcuts, from the exact reference render to fast.

Every shortcut is a switch of :class:`simulator.scene_config.SceneConfig` (scene) or
:class:`simulator.detector.camera_chain.CameraEffects` (camera), and each is decided per scene where it can be (a
still image shares one field; sub-poses follow the actual image shift; the heat shield is drawn only
when its footprint meets the view; smear fields are warped only when no pixel sees the sky).

=================  =========  =====  =======  =====
shortcut           reference  high   default  fast
=================  =========  =====  =======  =====
supersample        3 x 3      1      1        1
pixel-area filter  no         yes    yes      yes     (second-order stand-in for supersampling)
sub-poses/px shift 4          1      1        1 (max 4)
ray grid           exact      exact  16 px    32 px
photometry grid    exact      exact  16 px    32 px
still fields       no         no     < 1 px   < 3 px  (the window's shift; see below)
warped smear       no         no     yes      yes
warped blur        no         no     yes      yes     (>= 4 sub-poses: warp-and-accumulate, scene.blur_warp)
shot noise         Poisson    Poiss. Gauss.   Gauss.  (Gaussian above 1000 e-, see readout; same deviates)
binned render      no         no     no       yes     (one ray per 4-row block: descent_image)
edge rays          exact      exact  exact    interp. (heat-shield silhouette sub-pixel rays: scene.heat_shield)
=================  =========  =====  =======  =====

Fast's still threshold: a window (fast flush + exposure + frame transfer, three equal periods of the MER
camera) moving less than 3 terrain px moves less than ~1 px during the exposure, which then has one sub-pose
either way; the still path gives that same exposure field to the flush and transfer periods instead of their
own poses' (warped, ~1 px away). Their light enters only as column means (smear, (T_flush + T_transfer) x
the column's mean radiance): on the bench cases the images this changes move by 0.19-0.35 DN RMS (3 DN at
most) against the 2 px threshold, their error against the reference is unchanged (worst image 4.32 DN RMS)
and the velocity change stays at noise level; the worst direction, 2.5 px across the columns, moves the
image by 2.7 DN RMS (tests/simulator/test_fidelity.py).

The presets share their noise: the exact ones (``exact_poisson``) draw the default's per-pixel normal
deviates from the same stream and turn them into exact Poisson shot noise by inversion plus independent
Gaussian read noise (:mod:`simulator.detector.coupled_poisson`), so on the same seed every preset's image
carries the same noise (to 0.37 e- RMS above 1000 e-) and preset against preset compares the rendering alone.

Physics switches (shadows, heat shield, photometric correction, ...) and off-nominal effects are not
part of a preset: a preset changes how exactly the same physics is computed, never which physics.
``make bench`` (benchmarks/bench_fidelity.py) measures each preset's run time against its error.
"""
from __future__ import annotations

from typing import Literal

Preset = Literal["reference", "high", "default", "fast"]
PRESETS = ("reference", "high", "default", "fast")
DEFAULT_PRESET: Preset = "default"
#: Scene effect switches of the exact reference render (every shortcut off).
REFERENCE_EFFECTS = dict(coarse_ray_grid=False, coarse_photometry=False, share_still_fields=False,
                         warp_smear_fields=False, warp_motion_blur=False, pixel_area_filter=False,
                         binned_render=False, interpolated_edge_rays=False)


def preset_fields(name: str, max_substeps: int = 16) -> dict:
    """The ``[scene]`` values a fidelity preset sets (nested tables ``effects``, ``camera_effects``).

    Parameters
    ----------
    name : str
        Preset name (one of :data:`PRESETS`).
    max_substeps : int, optional
        The configuration's ``max_substeps`` (the reference render raises it to at least 64).

    Returns
    -------
    dict
        ``[scene]`` keys and values of the preset.

    Raises
    ------
    ValueError
        Unknown preset name (the message lists the allowed names).
    """
    if name not in PRESETS:
        raise ValueError(f"fidelity preset {name!r} is unknown; allowed: {', '.join(PRESETS)}")
    if name == "reference":
        return dict(effects=dict(REFERENCE_EFFECTS), supersample=3, substeps_per_terrain_px=4.0,
                    max_substeps=max(max_substeps, 64), camera_effects=dict(exact_poisson=True))
    if name == "high":
        return dict(effects={**REFERENCE_EFFECTS, "pixel_area_filter": True}, supersample=1,
                    substeps_per_terrain_px=1.0, camera_effects=dict(exact_poisson=True))
    fast = name == "fast"
    return dict(effects=dict(coarse_ray_grid=True, coarse_photometry=True, share_still_fields=True,
                             warp_smear_fields=True, warp_motion_blur=True, pixel_area_filter=True,
                             binned_render=fast, interpolated_edge_rays=fast),
                supersample=1, substeps_per_terrain_px=1.0, ray_grid_step_px=32 if fast else 16,
                photometry_grid_step_px=32 if fast else 16, still_shift_terrain_px=3.0 if fast else 1.0,
                max_substeps=4 if fast else max_substeps, camera_effects=dict(exact_poisson=False))
