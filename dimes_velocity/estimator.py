"""The reference DIMES velocity estimator: three descent images + measurements -> horizontal velocity.

Steps (paper section 5 and DESIGN.md "The reference estimator"):

1. pre-process each image (:mod:`.preprocess`): bin to 256 x 256, remove dark, fast-flush and
   frame-transfer smear, and divide by the flat field (a calibration product; the design falloff
   when there is none);
2. rectify each to a level, north-up ground grid (:mod:`.geometry`) at a common sampling (the nadir
   sampling of the highest image), assuming the lander at its IMU-predicted horizontal position and
   the radar altitude, with the measured attitude; flag what is not usable ground: off the image,
   saturated, no signal, the zero-phase zone (4.3 deg around the anti-sun direction) and the heat
   shield's cone when predicted;
3. for each consecutive pair (A, B): choose corner-like templates in A whose search window lies on
   usable ground of B (:mod:`.features`), find them in B (:mod:`.matching`). A feature seen at ground
   point ``g_A`` in A and ``g_B`` in B gives ``d = g_B - g_A``: both were placed with the
   IMU-predicted positions, so ``d = (predicted - true displacement) = bias * (t_B - t_A)``;
4. the agreeing majority of a pair's matches gives its bias; the pairs must agree within
   ``pair_agreement_mps`` (the bias is constant); the estimate is the IMU velocity at the last image
   minus the mean bias.
"""
from __future__ import annotations

import time
from collections import Counter
from typing import Sequence

import cv2
import numpy as np

from flight_interface.camera import Camera

from . import geometry
from .config import EstimatorConfig
from .features import interest_map, select_features
from .matching import match_template
from flight_interface.measurements import DescentMeasurements, MeasurementError, validate_measurements
from .preprocess import FlatImage, flatten, make_flattening
from .result import FeatureMetrics, PairResult, StageTimings, VelocityEstimate
from .solution import combine_pairs, consensus, weighted_displacement


MAX_BLUR_PX = 8.0   # cap on the resolution-equalising blur (images from very different altitudes)


class RectifiedImage:
    """One image on the ground grid, with its pyramid, masks and unusable-ground diagnosis."""

    def __init__(self, flat: FlatImage, rectification: geometry.Rectification, pose: geometry.CameraPose,
                 config: EstimatorConfig, blur_px: float = 0.0):
        self.rectification = rectification
        self.pose = pose
        self.flat = flat
        signal = flat.signal_dn
        if blur_px > 0.05:
            signal = cv2.GaussianBlur(signal, (0, 0), blur_px, borderType=cv2.BORDER_REPLICATE)
        self.image = geometry.warp(signal, rectification)
        # codes: 1 saturated, 2 no signal; dilated (max) so that every rectified pixel whose bilinear
        # support touches a bad block is bad, then carried over by nearest neighbour
        visible = rectification.visible.astype(bool)
        zone = rectification.excluded_zone.astype(bool)
        if flat.excluded.any():
            codes = np.where(flat.signal_dn < config.min_signal_dn, 2, flat.excluded).astype(np.uint8)
            codes = geometry.warp(cv2.dilate(codes, np.ones((3, 3), np.uint8)), rectification, cv2.INTER_NEAREST)
        else:
            codes = np.zeros(visible.shape, np.uint8)
        bad_pixel = codes > 0
        self.valid = visible & ~bad_pixel & ~zone
        self.coverage = float(np.count_nonzero(self.valid)) / self.valid.size
        self.unusable_reason = "ok"
        if self.coverage < config.min_ground_coverage:
            losses = {"sky": 1.0 - float(visible.mean()), "saturated": float((visible & (codes == 1)).mean()),
                      "no_signal": float((visible & (codes == 2)).mean()),
                      "excluded_zone": float((visible & zone & ~bad_pixel).mean())}
            self.unusable_reason = max(losses, key=losses.get)
        self.coarse = cv2.pyrDown(self.image)

    def noise_at(self, column: int, row: int) -> float:
        """Expected pixel noise (DN) of the source pixel seen at a rectified position."""
        rows, columns = self.flat.signal_dn.shape
        source_column = min(max(int(round(float(self.rectification.map_x[row, column]))), 0), columns - 1)
        source_row = min(max(int(round(float(self.rectification.map_y[row, column]))), 0), rows - 1)
        return self.flat.noise_dn_at(source_row, source_column)


def _erode(mask: np.ndarray, half: int) -> np.ndarray:
    """Pixels whose (2 half + 1)^2 neighbourhood is entirely inside ``mask`` (outside counts as False)."""
    if half <= 0:
        return mask.copy()
    kernel = np.ones((2 * half + 1, 2 * half + 1), np.uint8)
    return cv2.erode(mask.astype(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)


def _shifted(mask: np.ndarray, shift_columns: int, shift_rows: int) -> np.ndarray:
    """``out[v, u] = mask[v + shift_rows, u + shift_columns]`` (False outside)."""
    out = np.zeros_like(mask)
    rows, columns = mask.shape
    src_r0, src_c0 = max(shift_rows, 0), max(shift_columns, 0)
    dst_r0, dst_c0 = max(-shift_rows, 0), max(-shift_columns, 0)
    height, width = rows - abs(shift_rows), columns - abs(shift_columns)
    if height > 0 and width > 0:
        out[dst_r0:dst_r0 + height, dst_c0:dst_c0 + width] = mask[src_r0:src_r0 + height, src_c0:src_c0 + width]
    return out


class DimesEstimator:
    """The reference estimator for one camera and configuration (constants computed once).

    Parameters
    ----------
    camera : flight_interface.camera.Camera
    config : EstimatorConfig
    flat_field : ndarray, optional
        Measured relative response of each read-out pixel (a calibration product, shape
        ``camera.binned_shape``; :mod:`flight_interface.calibration`). None: the design falloff only.
    """

    def __init__(self, camera: Camera, config: EstimatorConfig = EstimatorConfig(),
                 flat_field: np.ndarray | None = None):
        self.camera = camera
        self.config = config
        self.flattening = make_flattening(camera, config, flat_field)
        self.focal_px = geometry.binned_focal_px(camera)

    def estimate(self, images: Sequence[np.ndarray], measurements: DescentMeasurements) -> VelocityEstimate:
        """Estimate the horizontal velocity at the last image.

        Parameters
        ----------
        images : sequence of ndarray
            Raw images as the camera returns them, shape ``(height / binning, width)`` (256 x 1024),
            integer or float DN; one per measurement, in time order (three for DIMES).
        measurements : DescentMeasurements

        Raises
        ------
        MeasurementError
            Illegal inputs only (wrong shapes, non-finite values, non-increasing times); any legal
            input returns a result, invalid with a reason when no trustworthy velocity is found.
        """
        start = time.perf_counter()
        config = self.config
        validate_measurements(measurements)
        if len(images) != len(measurements.images):
            raise MeasurementError(f"images: {len(images)} images for {len(measurements.images)} measurements")
        for k, image in enumerate(images):
            shape = np.shape(image)
            if shape != self.flattening.raw_shape:
                raise MeasurementError(f"image {k}: shape {shape}; expected {self.flattening.raw_shape}")
            if np.asarray(image).dtype.kind == "f" and not np.isfinite(image).all():
                raise MeasurementError(f"image {k}: contains non-finite values")
        flats = [flatten(image, self.flattening, config) for image in images]
        t_pre = time.perf_counter()

        positions = geometry.predicted_positions_m(measurements)
        poses = [geometry.camera_pose(self.camera, m.attitude_quat, m.radar_altitude_m, positions[k])
                 for k, m in enumerate(measurements.images)]
        heights = np.array([pose.centre_m[2] for pose in poses])
        sample_m = config.ground_sample_scale * max(float(heights.max()), 1.0) / self.focal_px
        sun = np.asarray(measurements.sun_direction_world, dtype=float)
        anti_sun = -sun / np.linalg.norm(sun)
        rectified: list[RectifiedImage | None] = []
        for k, (flat, pose, measurement) in enumerate(zip(flats, poses, measurements.images)):
            if pose.off_nadir_rad > config.max_off_nadir_rad or pose.centre_m[2] <= 0.0:
                rectified.append(None)
                continue
            shield = None
            half_angle = 0.0
            if measurement.heat_shield_offset_m is not None:
                lander = np.array([positions[k][0], positions[k][1], measurement.radar_altitude_m])
                shield = lander + np.asarray(measurement.heat_shield_offset_m, dtype=float)
                distance = max(float(np.linalg.norm(shield - pose.centre_m)), 1e-3)
                half_angle = float(np.arctan2(config.heat_shield_radius_m, distance)) + config.heat_shield_margin_rad
            rectification = geometry.rectify_map(
                pose, self.camera, config.rectified_size_px, sample_m,
                geometry.ground_centre_m(pose, config.max_off_nadir_rad), config.rectification_knots,
                anti_sun, config.zero_phase_half_angle_rad, shield, half_angle)
            ratio = sample_m * self.focal_px / pose.centre_m[2]
            blur = config.resolution_blur * np.sqrt(max(ratio * ratio - 1.0, 0.0)) if config.equalize_resolution else 0.0
            blur = min(blur, MAX_BLUR_PX)
            rectified.append(RectifiedImage(flat, rectification, pose, config, blur))
        t_rect = time.perf_counter()

        times = np.array([m.time_s for m in measurements.images])
        pairs: list[PairResult] = []
        features: list[FeatureMetrics] = []
        select_s = match_s = 0.0
        for k in range(len(images) - 1):
            pair, pair_features, t_sel, t_match = self._pair(k, rectified[k], rectified[k + 1],
                                                             float(times[k + 1] - times[k]))
            pairs.append(pair)
            features.extend(pair_features)
            select_s += t_sel
            match_s += t_match
        t_solve0 = time.perf_counter()

        valid, reason, bias = self._solve(pairs)
        imu_last = np.asarray(measurements.images[-1].imu_velocity_mps, dtype=float)[:2]
        velocity = imu_last - bias
        end = time.perf_counter()
        timings = StageTimings(
            preprocess_ms=1e3 * (t_pre - start), rectify_ms=1e3 * (t_rect - t_pre), select_ms=1e3 * select_s,
            match_ms=1e3 * match_s, solve_ms=1e3 * (end - t_solve0), total_ms=1e3 * (end - start))
        return VelocityEstimate(
            velocity_east_mps=float(velocity[0]), velocity_north_mps=float(velocity[1]), valid=valid, reason=reason,
            imu_bias_east_mps=float(bias[0]), imu_bias_north_mps=float(bias[1]), ground_sample_m=float(sample_m),
            pairs=tuple(pairs), features=tuple(features), timings=timings)

    # ----------------------------------------------------------------------------------------------
    def search_radius_px(self, a: RectifiedImage, b: RectifiedImage, dt_s: float) -> float:
        """Search radius (fine pixels) from the velocity-bias, attitude and altitude uncertainties."""
        config = self.config
        h_a, h_b = a.pose.centre_m[2], b.pose.centre_m[2]
        tilt = np.tan(min(max(a.pose.off_nadir_rad, b.pose.off_nadir_rad), config.max_off_nadir_rad))
        radius_m = (config.max_velocity_bias_mps * dt_s
                    + np.tan(config.attitude_uncertainty_rad) * abs(h_a - h_b)
                    + np.tan(config.relative_attitude_uncertainty_rad) * (h_a + h_b)
                    + config.altitude_uncertainty_fraction * (h_a + h_b) * tilt)
        radius = radius_m / a.rectification.sample_m + config.search_margin_px
        return float(min(radius, config.max_search_radius_px))

    def _pair(self, index: int, a: RectifiedImage | None, b: RectifiedImage | None, dt_s: float):
        """Select, match and combine the features of one image pair."""
        config = self.config
        t0 = time.perf_counter()

        def result(reason: str, radius: float = 0.0, matched: int = 0, used: int = 0,
                   displacement: np.ndarray | None = None) -> PairResult:
            ok = reason == "ok" and displacement is not None
            d = displacement if ok else np.zeros(2)
            return PairResult(index, index + 1, ok, reason, float(d[0]), float(d[1]), float(d[0] / dt_s),
                              float(d[1] / dt_s), float(radius), matched, used)

        for image in (a, b):
            if image is None:
                return result("bad_attitude"), [], time.perf_counter() - t0, 0.0
        for image in (a, b):
            if image.coverage < config.min_ground_coverage:
                return result(image.unusable_reason), [], time.perf_counter() - t0, 0.0
        radius = self.search_radius_px(a, b, dt_s)
        sample = a.rectification.sample_m
        shift = b.rectification.pixel_of(a.rectification.origin_m)        # B pixel of A's pixel (0, 0)
        half_t = max(config.template_size_px // 2, 2 * (config.coarse_template_size_px // 2) + 1)
        candidates = _erode(a.valid, half_t + config.border_margin_px)
        window_b = _erode(b.valid, half_t + int(np.ceil(radius)) + 2)
        shift_int = np.rint(shift).astype(int)
        candidates &= _shifted(window_b, int(shift_int[0]), int(shift_int[1]))
        if not candidates.any():
            return result("no_overlap", radius), [], time.perf_counter() - t0, 0.0
        selection = select_features(a.image, candidates, a.noise_at, config, interest_map(a.image, config))
        t1 = time.perf_counter()
        if not selection.features:
            reason = "low_contrast" if selection.low_contrast else "no_overlap"
            return result(reason, radius), [], t1 - t0, 0.0

        match_valid_b = _erode(b.valid, config.template_size_px // 2)
        records = []
        for rank, feature in enumerate(selection.features):
            predicted = np.array([feature.column, feature.row], dtype=float) + shift
            match = match_template(a.image, b.image, a.coarse, b.coarse, (feature.column, feature.row),
                                   predicted, radius, config)
            status = match.status
            column, row = np.rint(match.position_px).astype(int)
            if status == "ok" and not (0 <= row < match_valid_b.shape[0] and 0 <= column < match_valid_b.shape[1]
                                       and match_valid_b[row, column]):
                status = "match_in_excluded_area"
            ground_a = a.rectification.ground_of(feature.column, feature.row)
            displacement = (b.rectification.ground_of(*match.position_px) - ground_a) if status == "ok" else np.zeros(2)
            records.append([feature, match, status, ground_a, displacement])
        t2 = time.perf_counter()

        good = [i for i, record in enumerate(records) if record[2] == "ok"]
        group = consensus(np.array([records[i][4] for i in good]).reshape(-1, 2),
                          np.array([records[i][1].correlation for i in good]),
                          config.feature_agreement_px * sample, config.min_features_per_pair,
                          config.require_feature_majority)
        used = [good[j] for j in group]
        features = [FeatureMetrics(
            pair=index, index=rank, column_px=int(f.column), row_px=int(f.row), east_m=float(g[0]), north_m=float(g[1]),
            brightness_dn=f.brightness_dn, contrast_dn=f.contrast_dn, contrast_to_noise=f.contrast_to_noise,
            correlation=m.correlation, second_peak_ratio=m.second_peak_ratio, peak_curvature_per_px2=m.curvature_per_px2,
            displacement_east_m=float(d[0]), displacement_north_m=float(d[1]), status=s, used=rank in used)
            for rank, (f, m, s, g, d) in enumerate(records)]
        if not good:
            reason = Counter(record[2] for record in records).most_common(1)[0][0]
            return result(reason, radius), features, t1 - t0, t2 - t1
        if not used:
            return result("features_disagree", radius, len(good)), features, t1 - t0, t2 - t1
        displacement = weighted_displacement(np.array([records[i][4] for i in used]),
                                             np.array([records[i][1].correlation for i in used]))
        return result("ok", radius, len(good), len(used), displacement), features, t1 - t0, t2 - t1

    def _solve(self, pairs: list[PairResult]) -> tuple[bool, str, np.ndarray]:
        """Combine the pairs' bias estimates: (valid, reason, bias (2,) m/s)."""
        return combine_pairs(np.array([[p.bias_east_mps, p.bias_north_mps] for p in pairs]),
                             np.array([p.valid for p in pairs]), [p.reason for p in pairs],
                             self.config.pair_agreement_mps, self.config.require_both_pairs)


_CACHE: dict[tuple[int, int], tuple[Camera, EstimatorConfig, object, DimesEstimator]] = {}


def estimate_velocity(images: Sequence[np.ndarray], measurements: DescentMeasurements, camera: Camera,
                      config: EstimatorConfig = EstimatorConfig(),
                      flat_field: np.ndarray | None = None) -> VelocityEstimate:
    """Convenience wrapper: :meth:`DimesEstimator.estimate` with the estimator cached per camera, config
    and flat field (the same array object)."""
    key = (id(camera), id(flat_field))
    cached = _CACHE.get(key)
    if cached is None or cached[0] is not camera or cached[1] != config or cached[2] is not flat_field:
        if len(_CACHE) > 8:
            _CACHE.clear()
        cached = (camera, config, flat_field, DimesEstimator(camera, config, flat_field))
        _CACHE[key] = cached
    return cached[3].estimate(images, measurements)
