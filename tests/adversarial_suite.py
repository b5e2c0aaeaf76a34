"""The adversarial suite: :func:`build_suite` turns rendered descents (:mod:`adversarial_descents`)
into cases of every family, with the image and measurement manipulations below. Derandomized: one
seed gives the same cases (bit for bit) every run."""
from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from adversarial_descents import (
    FAMILIES,
    AdversarialCase,
    Descent,
    Renderer,
    lattice_terrain,
    multiply,
    quaternion,
    random_bias,
    random_descent,
    random_field,
    random_terrain,
    ripple_terrain,
)
from flight_interface.measurements import MeasurementError

ADVERSARIES = ("uncorrelated", "shifted_copy", "rotated_copy", "image_fixed_spots", "random_spots", "unmodelled_yaw",
               "unmodelled_tilt", "offset_gain_jump", "saturated_blobs", "heat_shield_occlusion")
OFFSET_DN, MAX_DN, BINNING = 20.0, 4095, 4


def _to_frame(raw: np.ndarray) -> np.ndarray:
    """Binned raw DN (256, 1024) -> a 1024 x 1024 frame of charge above the offset (4 equal rows)."""
    return np.repeat((raw.astype(np.float32) - OFFSET_DN) / BINNING, BINNING, axis=0)


def _to_raw(frame: np.ndarray) -> np.ndarray:
    summed = frame.reshape(-1, BINNING, frame.shape[1]).sum(axis=1) + OFFSET_DN
    return np.clip(np.rint(summed), 0, MAX_DN).astype(np.uint16)


def shifted(raw: np.ndarray, dx: float, dy: float) -> np.ndarray:
    """The image moved by (dx, dy) full-frame pixels (bilinear; uncovered edges repeat)."""
    matrix = np.float32([[1, 0, dx], [0, 1, dy]])
    return _to_raw(cv2.warpAffine(_to_frame(raw), matrix, (1024, 1024), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_REFLECT))


def rotated(raw: np.ndarray, angle_deg: float, centre) -> np.ndarray:
    matrix = cv2.getRotationMatrix2D((float(centre[0]), float(centre[1])), angle_deg, 1.0)
    return _to_raw(cv2.warpAffine(_to_frame(raw), matrix, (1024, 1024), flags=cv2.INTER_LINEAR,
                                  borderMode=cv2.BORDER_REFLECT))


def _box(frame: np.ndarray, column: float, row: float, reach: float):
    """Index box and (rows, columns) coordinates of the part of ``frame`` within ``reach`` of a point."""
    top, left = max(int(row - reach), 0), max(int(column - reach), 0)
    bottom, right = min(int(row + reach) + 2, frame.shape[0]), min(int(column + reach) + 2, frame.shape[1])
    rows, columns = np.mgrid[top:bottom, left:right].astype(np.float32)
    return (slice(top, bottom), slice(left, right)), rows, columns


def with_spots(raw: np.ndarray, spots) -> np.ndarray:
    """Add Gaussian spots (column, row, sigma in full-frame px, peak DN of a binned pixel)."""
    frame = _to_frame(raw)
    for column, row, sigma, peak in spots:
        box, rows, columns = _box(frame, column, row, 4 * sigma)
        r2 = (rows - row) ** 2 + (columns - column) ** 2
        frame[box] += np.float32(peak / BINNING) * np.exp(-r2 / (2.0 * sigma * sigma))
    return _to_raw(frame)


def with_discs(raw: np.ndarray, discs, value_dn: float | None) -> np.ndarray:
    """Discs (column, row, radius in full-frame px) set to ``value_dn`` (binned DN; None: saturated)."""
    frame = _to_frame(raw)
    for column, row, radius in discs:
        box, rows, columns = _box(frame, column, row, radius)
        inside = (rows - row) ** 2 + (columns - column) ** 2 <= radius * radius
        frame[box][inside] = 1e9 if value_dn is None else (value_dn - OFFSET_DN) / BINNING
    return _to_raw(frame)


def ground_pixel(renderer: Renderer, descent: Descent, image: int, east_north) -> tuple[float, float]:
    """Full-frame (column, row) where image ``image`` of ``descent`` sees ground point ``east_north``."""
    camera = renderer.camera
    from adversarial_descents import rotation

    body = rotation(descent.attitudes[image])
    to_world = body @ camera.camera_to_lander_matrix
    centre = descent.positions_m[image] + body @ camera.camera_position_in_lander_m + to_world @ camera.model.c
    rays = renderer.block_rays @ to_world.T
    distance = -centre[2] / np.minimum(rays[..., 2], -1e-6)
    east = centre[0] + distance * rays[..., 0]
    north = centre[1] + distance * rays[..., 1]
    block = np.unravel_index(np.argmin((east - east_north[0]) ** 2 + (north - east_north[1]) ** 2), east.shape)
    return BINNING * block[1] + 1.5, BINNING * block[0] + 1.5


def ground_point(renderer: Renderer, descent: Descent, image: int, column: float, row: float) -> np.ndarray:
    camera = renderer.camera
    from adversarial_descents import rotation

    body = rotation(descent.attitudes[image])
    to_world = body @ camera.camera_to_lander_matrix
    centre = descent.positions_m[image] + body @ camera.camera_position_in_lander_m + to_world @ camera.model.c
    ray = renderer.block_rays[int(row) // BINNING, int(column) // BINNING] @ to_world.T
    return centre[:2] + (-centre[2] / min(ray[2], -1e-6)) * ray[:2]


def strongest_corners(raw: np.ndarray, count: int) -> list[tuple[float, float]]:
    """Full-frame (column, row) of the ``count`` strongest Shi-Tomasi corners of the 256 x 256 block
    image (the generator's own choice, independent of the estimator's feature selection)."""
    blocks = raw.astype(np.float32).reshape(256, 256, BINNING).sum(axis=2)
    corners = cv2.goodFeaturesToTrack(blocks, count, 0.01, 12, blockSize=15, useHarrisDetector=False)
    if corners is None:
        return [(512.0, 512.0)]
    return [(BINNING * c + 1.5, BINNING * r + 1.5) for c, r in corners.reshape(-1, 2)]


def adversary(family: str, descent: Descent, other: Descent, renderer: Renderer,
              rng: np.random.Generator) -> AdversarialCase:
    """One case of ``family`` from ``descent`` (``other``: a descent elsewhere, for ``uncorrelated``)."""
    images = [image.copy() for image in descent.images]
    bias = random_bias(rng)
    target = int(rng.integers(1, 3))                  # the image that is tampered with (or 0 .. 2 below)
    if family == "uncorrelated":
        images[target] = other.images[target].copy()
    elif family == "shifted_copy":
        source = target - 1 if rng.random() < 0.7 else (target + 1) % 3
        images[target] = shifted(images[source], *rng.uniform(-40.0, 40.0, size=2))
    elif family == "rotated_copy":
        source = target - 1
        images[target] = rotated(images[source], rng.choice([-1, 1]) * rng.uniform(2.0, 30.0),
                                 rng.uniform(300.0, 724.0, size=2))
    elif family == "image_fixed_spots":         # dust, hot pixels: scattered, or clustered so that they agree
        centre, reach = rng.uniform(200.0, 824.0, size=2), (rng.uniform(20.0, 80.0) if rng.random() < 0.5 else 450.0)
        spots = [(*np.clip(centre + rng.uniform(-reach, reach, size=2), 32.0, 992.0), rng.uniform(1.0, 4.0),
                  rng.uniform(300.0, 3000.0)) for _ in range(int(rng.integers(2, 13)))]
        images = [with_spots(image, spots) for image in images]
    elif family == "random_spots":
        images = [with_spots(image, [(*rng.uniform(64.0, 960.0, size=2), rng.uniform(1.0, 4.0),
                                      rng.uniform(300.0, 3000.0)) for _ in range(int(rng.integers(2, 13)))])
                  for image in images]
    elif family in ("unmodelled_yaw", "unmodelled_tilt"):
        attitudes = list(descent.attitudes)
        if family == "unmodelled_yaw":
            error = quaternion([0, 0, 1], np.radians(rng.choice([-1, 1]) * rng.uniform(4.0, 30.0)))
        else:
            axis = rng.uniform(0.0, 2.0 * np.pi)
            error = quaternion([np.cos(axis), np.sin(axis), 0.0], np.radians(rng.uniform(1.5, 10.0)))
        changed = [target] if rng.random() < 0.5 else [1, 2]   # one image, or the lander turned after image 1
        for k in changed:
            attitudes[k] = multiply(error, attitudes[k])
        return descent.case(family, images, bias, attitudes)
    elif family == "offset_gain_jump":
        gain, offset = rng.uniform(0.5, 2.0), rng.uniform(-100.0, 400.0)
        images[target] = np.clip((images[target].astype(np.float32) - OFFSET_DN) * gain + OFFSET_DN + offset,
                                 0, MAX_DN).astype(np.uint16)
    elif family == "saturated_blobs":
        discs = [(*rng.uniform(32.0, 992.0, size=2), rng.uniform(8.0, 60.0)) for _ in range(int(rng.integers(1, 7)))]
        chosen = range(3) if rng.random() < 0.5 else [target]
        for k in chosen:
            images[k] = with_discs(images[k], discs, None)
    elif family == "heat_shield_occlusion":
        radius = rng.uniform(12.0, 40.0)
        dark = rng.uniform(25.0, 120.0)
        mode = rng.integers(0, 3)
        if mode == 0:     # covers where a strong template of the previous image is seen in this one
            source = target - 1
            column, row = strongest_corners(images[source], 3)[int(rng.integers(0, 3))]
            point = ground_point(renderer, descent, source, column, row)
            centre = np.array(ground_pixel(renderer, descent, target, point)) + rng.uniform(-0.5, 0.5, 2) * radius
            images[target] = with_discs(images[target], [(*centre, radius)], dark)
        else:             # the shield moves across two (mode 1) or all three images, not where predicted
            start = rng.uniform(200.0, 824.0, size=2)
            step = rng.uniform(-60.0, 60.0, size=2)
            shown = [target - 1, target] if mode == 1 else [0, 1, 2]
            for n, k in enumerate(shown):
                images[k] = with_discs(images[k], [(*(start + n * step), radius)], dark)
    else:
        raise ValueError(f"unknown family {family!r}")
    return descent.case(family, images, bias)


BLAND_ADVERSARIES = ("image_fixed_spots", "random_spots", "saturated_blobs", "heat_shield_occlusion")


def build_suite(camera, seed: int = 2026, descents: int = 70, bland: int = 20, repetitive: int = 20,
                biases_per_repetitive: int = 6) -> list[AdversarialCase]:
    """``descents`` descents over textured ground (each an ``ordinary`` case plus one case of every
    adversary), ``bland`` descents over nearly featureless ground (relative contrast 0.4-1 %: the
    planted spots, blobs and heat shields are then the only features; one case of each of
    :data:`BLAND_ADVERSARIES`), ``repetitive`` dune-ripple and as many crater-lattice descents (four
    per terrain, each with ``biases_per_repetitive`` IMU biases anywhere within the estimator's
    prior, so that an alias can be nearer the prediction than the truth). Defaults:
    70 x 11 + 20 x 4 + 2 x 20 x 6 = 1090 cases, then ``descents`` ``implausible_record`` cases (the
    textured descents' images with a self-contradicting record): 1160."""
    renderer = Renderer(camera)
    root = np.random.SeedSequence(seed)
    # spawned children do not depend on the count: the sixth (implausible records) changed no other case
    ground_seeds, descent_seeds, repetitive_seeds, bland_seeds, draw_seed, record_seed = root.spawn(6)
    grounds = [random_terrain(np.random.default_rng(s), contrast)
               for s, contrast in zip(ground_seeds.spawn(8), np.linspace(0.04, 0.16, 8))]
    rendered = [random_descent(renderer, grounds[k % len(grounds)], np.random.default_rng(s))
                for k, s in enumerate(descent_seeds.spawn(descents))]
    cases: list[AdversarialCase] = []
    rng = np.random.default_rng(draw_seed)
    for k, descent in enumerate(rendered):
        cases.append(descent.case("ordinary", bias_mps=random_bias(rng)))
        other = rendered[(k + len(rendered) // 2) % len(rendered)]
        for family in ADVERSARIES:
            cases.append(adversary(family, descent, other, renderer, rng))
    bland_grounds = [random_terrain(np.random.default_rng(s), contrast)
                     for s, contrast in zip(bland_seeds.spawn(2), (0.004, 0.01))]
    for k, s in enumerate(bland_seeds.spawn(bland)):
        descent = random_descent(renderer, bland_grounds[k % 2], np.random.default_rng(s))
        for family in BLAND_ADVERSARIES:
            cases.append(adversary(family, descent, descent, renderer, rng))
    background_seed, terrain_seed, repetitive_descents = repetitive_seeds.spawn(3)
    background = random_field(np.random.default_rng(background_seed))
    terrain_rng = np.random.default_rng(terrain_seed)
    per_terrain = 4
    terrains = {family: [maker(terrain_rng, background) for _ in range(-(-repetitive // per_terrain))]
                for family, maker in (("dune_ripples", ripple_terrain), ("crater_lattice", lattice_terrain))}
    for k, s in enumerate(repetitive_descents.spawn(2 * repetitive)):
        local = np.random.default_rng(s)
        family = "dune_ripples" if k % 2 == 0 else "crater_lattice"
        descent = random_descent(renderer, terrains[family][(k // 2) // per_terrain], local)
        for _ in range(biases_per_repetitive):
            cases.append(descent.case(family, bias_mps=random_bias(local, 25.0)))
    record_rng = np.random.default_rng(record_seed)
    for k, descent in enumerate(rendered):
        cases.append(implausible_record(descent, record_rng, jump=k % 2 == 0))
    assert {case.family for case in cases} <= set(FAMILIES)
    return cases


def implausible_record(descent: Descent, rng: np.random.Generator, jump: bool) -> AdversarialCase:
    """The descent's own images with a record that contradicts itself (issue 31): the middle IMU velocity
    10-27 m/s off in any direction (``jump``), or all three radar altitudes x 1.15-1.4 or x 0.6-0.85."""
    case = descent.case("implausible_record", bias_mps=random_bias(rng, 10.0))
    images = list(case.measurements.images)
    if jump:
        size, angle = rng.uniform(10.0, 27.0), rng.uniform(0.0, 2.0 * np.pi)
        step = size * np.array([np.cos(angle), np.sin(angle), 0.0])
        images[1] = dataclasses.replace(images[1], imu_velocity_mps=images[1].imu_velocity_mps + step)
    else:
        factor = rng.uniform(1.15, 1.4) if rng.random() < 0.5 else rng.uniform(0.6, 0.85)
        images = [dataclasses.replace(m, radar_altitude_m=m.radar_altitude_m * factor) for m in images]
    measurements = dataclasses.replace(case.measurements, images=tuple(images))
    return AdversarialCase(case.family, case.images, measurements, case.truth_velocity_mps)


FALSE_VALID_MPS = 5.0
#: The outcome recorded when the estimator refuses the case's record (MeasurementError).
INPUT_ERROR = "input_error"
FALSE_VALID_SIGMAS = 3.0


def false_valid(error_mps: float, uncertainty_mps: float) -> bool:
    """Valid but wrong: horizontal error above 5 m/s, or above 3 x the estimate's own stated uncertainty."""
    return error_mps > FALSE_VALID_MPS or error_mps > FALSE_VALID_SIGMAS * uncertainty_mps


def evaluate(cases: list[AdversarialCase], estimator) -> tuple[list[dict], list[dict]]:
    """Run ``estimator`` on every case: one summary row per family (cases, % valid, false-valid,
    worst valid error, most frequent reasons) and the records of every case."""
    records = []
    for index, case in enumerate(cases):
        try:
            result = estimator.estimate(case.images, case.measurements)
        except MeasurementError:      # refused as an input error (exit 2 in the CLI): never valid
            records.append({"index": index, "family": case.family, "valid": False, "reason": INPUT_ERROR,
                            "error_mps": float("nan"), "uncertainty_mps": 0.0, "false_valid": False})
            continue
        error = float(np.hypot(result.velocity_east_mps - case.truth_velocity_mps[0],
                               result.velocity_north_mps - case.truth_velocity_mps[1]))
        records.append({"index": index, "family": case.family, "valid": result.valid, "reason": result.reason,
                        "error_mps": error if result.valid else float("nan"),
                        "uncertainty_mps": result.velocity_uncertainty_mps,
                        "false_valid": result.valid and false_valid(error, result.velocity_uncertainty_mps)})
    rows = []
    for family in FAMILIES:
        members = [r for r in records if r["family"] == family]
        if not members:
            continue
        valid = [r for r in members if r["valid"]]
        reasons: dict[str, int] = {}
        for r in members:
            reasons[r["reason"]] = reasons.get(r["reason"], 0) + 1
        rows.append({"family": family, "cases": len(members), "valid": len(valid),
                     "pct_valid": 100.0 * len(valid) / len(members),
                     "false_valid": sum(r["false_valid"] for r in members),
                     "worst_valid_error_mps": max((r["error_mps"] for r in valid), default=float("nan")),
                     "reasons": ", ".join(f"{k} {v}" for k, v in sorted(reasons.items(), key=lambda kv: -kv[1])[:3])})
    return rows, records


def format_rows(rows: list[dict]) -> str:
    lines = ["| family | cases | % valid | false-valid | worst valid error (m/s) | most frequent outcomes |",
             "|---|---|---|---|---|---|"]
    for row in rows:
        worst = "n/a" if np.isnan(row["worst_valid_error_mps"]) else f"{row['worst_valid_error_mps']:.2f}"
        lines.append(f"| {row['family']} | {row['cases']} | {row['pct_valid']:.0f}% | {row['false_valid']} | "
                     f"{worst} | {row['reasons']} |")
    return "\n".join(lines)
