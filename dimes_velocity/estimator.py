"""The reference DIMES velocity estimator: three descent images + measurements -> horizontal velocity.

Steps (paper section 5):

1. pre-process each image (:mod:`.preprocess`): bin to 256 x 256, remove dark, fast-flush and
   frame-transfer smear, and divide by the flat field (a calibration product; the design falloff
   when there is none);
2. rectify each to a level, north-up ground grid (:mod:`.geometry`) at a common sampling (the nadir
   sampling of the highest image), assuming the lander at its IMU-predicted horizontal position and
   the radar altitude, with the measured attitude; flag what is not usable ground: off the image,
   saturated, no signal, the zero-phase zone (4.3 deg around the anti-sun direction) and the heat
   shield's cone when predicted;
3. for each consecutive pair (A, B): choose corner-like templates in A whose search window lies on
   usable ground of B (:mod:`.features`), find them in B (:mod:`.matching`), in order of interest
   until ``agreeing_features_to_stop`` good matches agree (at most ``features_per_pair``). A match
   counts only when its peak is distinct, sharp, within the prior and correlated enough
   (:mod:`.matching`), it lies on usable ground, it moved in the raw image (not a mark on the optics
   or detector) and its decorrelation is what the pixel noise explains (:class:`_MatchCheck`). A
   feature seen at ground point ``g_A`` in A and ``g_B`` in B gives ``d = g_B - g_A``: both were
   placed with the IMU-predicted positions, so ``d = (predicted - true displacement) = bias * (t_B - t_A)``;
4. the agreeing majority of a pair's matches (at least ``min_features_per_pair`` templates that share
   no pixel) gives its bias; the pairs must agree within ``pair_agreement_mps`` (the bias is
   constant); the estimate is the IMU velocity at the last image minus the mean bias, with its
   stated uncertainty (:func:`.solution.velocity_uncertainty`).

How this follows the flight DIMES algorithm is in the package docstring (:mod:`dimes_velocity`).
"""
from __future__ import annotations

import math
import time
from collections.abc import Sequence

import cv2
import numpy as np

from dimes_velocity import compiled, geometry
from dimes_velocity.config import EstimatorConfig
from dimes_velocity.features import Candidate, FeatureSelector
from dimes_velocity.matching import Match, match_template
from dimes_velocity.preprocess import FlatImage, flatten, make_flattening
from dimes_velocity.result import FeatureMetrics, PairResult, StageTimings, VelocityEstimate, failed_pair_reason
from dimes_velocity.solution import (
    combine_pairs,
    consensus,
    displacement_standard_error,
    implied_bias_limit_mps,
    velocity_uncertainty,
    weighted_displacement,
)
from flight_interface.camera import Camera
from flight_interface.measurements import DescentMeasurements, MeasurementError, validate_measurements

MAX_BLUR_PX = 8.0   # cap on the resolution-equalising blur (images from very different altitudes)
MATCH_PRECISION_PX = 0.1   # floor of a pair's displacement standard error (sub-pixel peak precision)
_KERNEL_3X3 = np.ones((3, 3), np.uint8)


class RectifiedImage:
    """One image on the ground grid, with its pyramid, masks and unusable-ground diagnosis.

    Parameters
    ----------
    flat : FlatImage
        The binned, flattened image.
    rectification : Rectification
        Its map onto the ground grid.
    pose : CameraPose
        The image's camera as measured.
    config : EstimatorConfig
        ``min_signal_dn`` and ``min_ground_coverage``.
    blur_px : float, optional
        Standard deviation of a Gaussian blur of the binned image before rectification (binned px):
        brings a lower image to the common ground resolution.
    """

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
        visible = rectification.visible.view(bool)          # 0/1 uint8 seen as bool (no copy)
        zone = rectification.excluded_zone.view(bool)
        codes: np.ndarray | None = None
        bad_pixel: np.ndarray | None = None
        if flat.excluded.any():
            codes = np.where(flat.signal_dn < config.min_signal_dn, 2, flat.excluded).astype(np.uint8)
            codes = geometry.warp(cv2.dilate(codes, _KERNEL_3X3), rectification, cv2.INTER_NEAREST)
            bad_pixel = codes > 0
            self.valid = visible & ~bad_pixel & ~zone
        else:                                                # no bad block: nothing to carry over
            self.valid = np.greater(rectification.visible, rectification.excluded_zone)   # 0/1: visible & ~zone
        self.coverage = float(np.count_nonzero(self.valid)) / self.valid.size
        self.unusable_reason = "ok"
        if self.coverage < config.min_ground_coverage:
            if codes is None or bad_pixel is None:
                codes, bad_pixel = np.zeros(visible.shape, np.uint8), np.zeros(visible.shape, bool)
            losses = {"sky": 1.0 - float(visible.mean()), "saturated": float((visible & (codes == 1)).mean()),
                      "no_signal": float((visible & (codes == 2)).mean()),
                      "excluded_zone": float((visible & zone & ~bad_pixel).mean())}
            self.unusable_reason = max(losses, key=losses.__getitem__)
        self.coarse = cv2.pyrDown(self.image)

    def noise_at(self, column: int, row: int) -> float:
        """Expected pixel noise of the source pixel seen at a rectified position.

        Parameters
        ----------
        column, row : int
            Rectified pixel position (px).

        Returns
        -------
        float
            Noise standard deviation (flattened DN).
        """
        rows, columns = self.flat.signal_dn.shape
        source_column = min(max(int(round(float(self.rectification.map_x[row, column]))), 0), columns - 1)
        source_row = min(max(int(round(float(self.rectification.map_y[row, column]))), 0), rows - 1)
        return self.flat.noise_dn_at(source_row, source_column)


_SCALAR_POINTS = 12      # up to this many points, pairwise distances in Python scalars (fewer calls than numpy)


def _largest_distance(points) -> float:
    """Largest distance between 2-D points (0 for none).

    ``np.linalg.norm(p[:, None] - p[None], axis=-1).max()``: ``sqrt(dx * dx + dy * dy)`` (the same rounding: a
    sum of two squares, a correctly rounded square root), in Python scalars for a few points.
    """
    values = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(values) > _SCALAR_POINTS:
        return float(np.linalg.norm(values[:, None] - values[None], axis=-1).max())
    pairs = values.tolist()
    squares = [(x - other_x) * (x - other_x) + (y - other_y) * (y - other_y)
               for k, (x, y) in enumerate(pairs) for other_x, other_y in pairs[k + 1:]]
    if any(square != square for square in squares):       # NaN, as numpy's max
        return math.nan
    return math.sqrt(max(squares, default=0.0))


def _span(centres_px) -> float:
    """Largest distance between template centres (px)."""
    return _largest_distance(centres_px)


def _all_agree(displacements_m: list, centres_px: list, count: int, tolerance_m: float, min_span_px: float) -> bool:
    """At least ``count`` displacements, all within ``tolerance_m`` of each other.

    The templates must span at least ``min_span_px``: then there is enough agreeing evidence to stop tracking.
    """
    if len(displacements_m) < count:
        return False
    return (_largest_distance(displacements_m) <= tolerance_m
            and (len(displacements_m) == 1 or _span(centres_px) >= min_span_px))


def _erode(mask: np.ndarray, half: int) -> np.ndarray:
    """Pixels whose (2 half + 1)^2 neighbourhood is entirely inside ``mask`` (outside counts as False).

    ``cv2.erode`` by the square with a constant 0 border, separably: along the columns, then along the rows (the
    columns of the transpose), each pass one run counter per column (:func:`compiled.erode_columns`): its cost does
    not grow with the square (a 91 px square ~4x faster than OpenCV's).
    """
    if half <= 0:
        return mask.copy()
    side = 2 * half + 1
    source = np.ascontiguousarray(mask, dtype=bool).view(np.uint8)          # 0/1, no copy
    down = compiled.erode_columns(source, side)
    return cv2.transpose(compiled.erode_columns(cv2.transpose(down), side)).view(bool)


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


def _variance(window: np.ndarray) -> float:
    """``float(window.astype(np.float64).var())`` with the same float64 reductions (:func:`compiled.variance`)."""
    return float(compiled.variance(window))


class _MatchCheck:
    """What a match is checked against besides its correlation surface.

    Where template and match are in the raw images (a mark on the optics or detector does not move), whether the
    match is on usable ground, and how much decorrelation the pixel noise of template and match explains.
    """

    def __init__(self, a: RectifiedImage, b: RectifiedImage, feature, match, config: EstimatorConfig,
                 noise_a: float | None = None):
        self.column, self.row = round(float(match.position_px[0])), round(float(match.position_px[1]))   # = np.rint
        size = b.image.shape
        self.inside = 0 <= self.row < size[0] and 0 <= self.column < size[1]
        self.image_motion_px = 0.0
        self.noise_decorrelation = 0.0
        if not (self.inside and match.status == "ok"):
            return
        map_a, map_b = a.rectification, b.rectification
        self.image_motion_px = float(np.hypot(
            float(map_b.map_x[self.row, self.column]) - float(map_a.map_x[feature.row, feature.column]),
            float(map_b.map_y[self.row, self.column]) - float(map_a.map_y[feature.row, feature.column])))
        half = config.template_size_px // 2
        window = b.image[max(self.row - half, 0): self.row + half + 1, max(self.column - half, 0): self.column + half + 1]
        noise_a = a.noise_at(feature.column, feature.row) if noise_a is None else noise_a
        noise_b = b.noise_at(self.column, self.row)
        signal_a = max(feature.contrast_dn ** 2 - noise_a ** 2, 1e-12)
        signal_b = max(_variance(window) - noise_b ** 2, 1e-12)
        self.noise_decorrelation = 0.5 * (noise_a ** 2 / signal_a + noise_b ** 2 / signal_b)

    def on_usable_ground(self, valid_b: np.ndarray, half: int) -> bool:
        """The match's whole template, ``(2 half + 1)^2`` around it, lies on usable ground of B.

        ``_erode(valid_b, half)`` at the match, without eroding the whole image: outside the image is not usable.
        """
        row, column = self.row, self.column
        rows, columns = valid_b.shape
        if not self.inside or row < half or column < half or row + half >= rows or column + half >= columns:
            return False
        return bool(valid_b[row - half: row + half + 1, column - half: column + half + 1].all())


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
            Measured attitude, radar altitude, IMU velocity per image; the sun direction.

        Returns
        -------
        VelocityEstimate
            The velocity (m/s, world east and north), validity and reason, stated uncertainty, IMU bias,
            per-pair and per-feature results and stage timings.

        Raises
        ------
        MeasurementError
            Illegal inputs only (wrong shapes, non-finite values, non-increasing times); any legal
            input returns a result, invalid with a reason when no trustworthy velocity is found.

        Notes
        -----
        OpenCV runs on one thread inside (restored after): on 256 x 256 images its thread hand-off
        costs more than it saves, and on a loaded machine (one campaign worker per core) a parallel
        call waits for a second thread's time slice. The results do not depend on it.
        """
        threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            return self._estimate(images, measurements)
        finally:
            cv2.setNumThreads(threads)

    def _estimate(self, images: Sequence[np.ndarray], measurements: DescentMeasurements) -> VelocityEstimate:
        """:meth:`estimate` (OpenCV's thread count already set)."""
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
        sun_up = -float(anti_sun[2])            # sine of the sun elevation; <= 0: no sunlit ground to track
        unusable: list[str] = []
        requests: list[geometry.RectificationRequest] = []
        for k, (pose, measurement) in enumerate(zip(poses, measurements.images)):
            if sun_up <= 0.0 or pose.off_nadir_rad > config.max_off_nadir_rad or pose.centre_m[2] <= 0.0:
                unusable.append("sun_below_horizon" if sun_up <= 0.0 else "bad_attitude")
                continue
            unusable.append("")
            shield = None
            half_angle = 0.0
            if measurement.heat_shield_offset_m is not None:
                lander = np.array([positions[k][0], positions[k][1], measurement.radar_altitude_m])
                shield = lander + np.asarray(measurement.heat_shield_offset_m, dtype=float)
                distance = max(float(np.linalg.norm(shield - pose.centre_m)), 1e-3)
                half_angle = float(np.arctan2(config.heat_shield_radius_m, distance)) + config.heat_shield_margin_rad
            requests.append(geometry.RectificationRequest(
                pose, geometry.ground_centre_m(pose, config.max_off_nadir_rad), shield, half_angle))
        # all the usable images' maps at once (one interpolation of their knot maps)
        rectifications = iter(geometry.rectify_maps(requests, self.camera, config.rectified_size_px, sample_m,
                                                    config.rectification_knots, anti_sun,
                                                    config.zero_phase_half_angle_rad))
        rectified: list[RectifiedImage | None] = []
        for flat, pose, reason in zip(flats, poses, unusable):
            if reason:
                rectified.append(None)
                continue
            ratio = sample_m * self.focal_px / pose.centre_m[2]
            blur = config.resolution_blur * np.sqrt(max(ratio * ratio - 1.0, 0.0)) if config.equalize_resolution else 0.0
            blur = min(blur, MAX_BLUR_PX)
            rectified.append(RectifiedImage(flat, next(rectifications), pose, config, blur))
        t_rect = time.perf_counter()

        times = np.array([m.time_s for m in measurements.images])
        pairs: list[PairResult] = []
        features: list[FeatureMetrics] = []
        select_s = match_s = 0.0
        for k in range(len(images) - 1):
            pair, pair_features, t_sel, t_match = self._pair(k, rectified[k], rectified[k + 1],
                                                             float(times[k + 1] - times[k]),
                                                             unusable[k] or unusable[k + 1])
            pairs.append(pair)
            features.extend(pair_features)
            select_s += t_sel
            match_s += t_match
        t_solve0 = time.perf_counter()

        valid, reason, bias = self._solve(pairs)
        uncertainty = self._uncertainty(pairs, poses, times) if valid else 0.0
        if valid and float(np.hypot(bias[0], bias[1])) > implied_bias_limit_mps(
                uncertainty, config.imu_velocity_bias_sigma_mps, config.implied_bias_confidence):
            valid, reason, bias, uncertainty = False, "imu_bias_implausible", np.zeros(2), 0.0
        imu_last = np.asarray(measurements.images[-1].imu_velocity_mps, dtype=float)[:2]
        velocity = imu_last - bias
        end = time.perf_counter()
        timings = StageTimings(
            preprocess_ms=1e3 * (t_pre - start), rectify_ms=1e3 * (t_rect - t_pre), select_ms=1e3 * select_s,
            match_ms=1e3 * match_s, solve_ms=1e3 * (end - t_solve0), total_ms=1e3 * (end - start))
        return VelocityEstimate(
            velocity_east_mps=float(velocity[0]), velocity_north_mps=float(velocity[1]), valid=valid, reason=reason,
            velocity_uncertainty_mps=uncertainty,
            imu_bias_east_mps=float(bias[0]), imu_bias_north_mps=float(bias[1]), ground_sample_m=float(sample_m),
            pairs=tuple(pairs), features=tuple(features), timings=timings)

    # ----------------------------------------------------------------------------------------------
    def search_radius_px(self, a: RectifiedImage, b: RectifiedImage, dt_s: float) -> float:
        """Search radius from the velocity-bias, attitude and altitude uncertainties.

        Parameters
        ----------
        a, b : RectifiedImage
            The pair's first and second image.
        dt_s : float
            Time between them (s).

        Returns
        -------
        float
            Radius (fine rectified px), plus ``search_margin_px``, at most ``max_search_radius_px``.
        """
        config = self.config
        h_a, h_b = a.pose.centre_m[2], b.pose.centre_m[2]
        tilt = np.tan(min(max(a.pose.off_nadir_rad, b.pose.off_nadir_rad), config.max_off_nadir_rad))
        radius_m = (config.max_velocity_bias_mps * dt_s
                    + np.tan(config.attitude_uncertainty_rad) * abs(h_a - h_b)
                    + np.tan(config.relative_attitude_uncertainty_rad) * (h_a + h_b)
                    + config.altitude_uncertainty_fraction * (h_a + h_b) * tilt)
        radius = radius_m / a.rectification.sample_m + config.search_margin_px
        return float(min(radius, config.max_search_radius_px))

    def _pair(self, index: int, a: RectifiedImage | None, b: RectifiedImage | None, dt_s: float,
              unusable_reason: str = "bad_attitude"):
        """Select, match and combine the features of one image pair.

        ``unusable_reason``: why an image given as None cannot be used.
        """
        config = self.config
        t0 = time.perf_counter()

        def result(reason: str, radius: float = 0.0, matched: int = 0, used: int = 0,
                   displacement: np.ndarray | None = None, sigma_m: float = 0.0) -> PairResult:
            ok = reason == "ok" and displacement is not None
            d = displacement if ok and displacement is not None else np.zeros(2)
            return PairResult(index, index + 1, ok, reason, float(d[0]), float(d[1]), float(d[0] / dt_s),
                              float(d[1] / dt_s), float(sigma_m) if ok else 0.0, float(radius), matched, used)

        if a is None or b is None:
            return result(unusable_reason), [], time.perf_counter() - t0, 0.0
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
        selector = FeatureSelector(a.image, candidates, a.noise_at, config)   # interest where centres may be
        feature = selector.next()
        t1 = time.perf_counter()
        if feature is None:
            reason = "low_contrast" if selector.low_contrast else "no_overlap"
            return result(reason, radius), [], t1 - t0, 0.0

        # feature, match, status, ground position in A, displacement, checks
        records: list[tuple[Candidate, Match, str, np.ndarray, np.ndarray, _MatchCheck]] = []
        select_s = 0.0
        while feature is not None:
            predicted = np.array([feature.column, feature.row], dtype=float) + shift
            rows, columns = b.image.shape
            noise_b = b.noise_at(min(max(int(round(float(predicted[0]))), 0), columns - 1),
                                 min(max(int(round(float(predicted[1]))), 0), rows - 1))
            noise_a = a.noise_at(feature.column, feature.row)
            match = match_template(a.image, b.image, a.coarse, b.coarse, (feature.column, feature.row),
                                   predicted, radius, config, noise_a, noise_b)
            check = _MatchCheck(a, b, feature, match, config, noise_a)
            status = match.status
            if status == "ok" and not check.on_usable_ground(b.valid, config.template_size_px // 2):
                status = "match_in_excluded_area"
            elif status == "ok" and check.image_motion_px < config.min_image_motion_px:
                status = "camera_fixed"
            elif status == "ok" and (1.0 - match.correlation > config.max_noise_decorrelation_ratio
                                     * check.noise_decorrelation + config.decorrelation_allowance):
                status = "residual_exceeds_noise"
            ground_a = a.rectification.ground_of(feature.column, feature.row)
            displacement = (b.rectification.ground_of(*match.position_px) - ground_a) if status == "ok" else np.zeros(2)
            records.append((feature, match, status, ground_a, displacement, check))
            good_so_far = [r for r in records if r[2] == "ok"]
            if status == "ok" and _all_agree([r[4] for r in good_so_far], [(r[0].column, r[0].row) for r in good_so_far],
                                             config.agreeing_features_to_stop, config.feature_agreement_px * sample,
                                             config.min_group_span_px):
                break
            if len(records) == config.features_per_pair:
                break
            started = time.perf_counter()
            feature = selector.next()
            select_s += time.perf_counter() - started
        t2 = time.perf_counter()
        t1 += select_s

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
            coarse_peak_curvature_per_px2=m.coarse_curvature_per_px2, noise_decorrelation=c.noise_decorrelation,
            image_motion_px=c.image_motion_px, displacement_east_m=float(d[0]), displacement_north_m=float(d[1]),
            status=s, used=rank in used)
            for rank, (f, m, s, g, d, c) in enumerate(records)]
        if not good:
            return result(failed_pair_reason([record[2] for record in records]), radius), features, t1 - t0, t2 - t1
        if not used:
            reason = "too_few_features" if len(good) < config.min_features_per_pair else "features_disagree"
            if reason == "too_few_features":
                reason = failed_pair_reason([record[2] for record in records], reason)
            return result(reason, radius, len(good)), features, t1 - t0, t2 - t1
        if len(used) > 1 and _span([(records[i][0].column, records[i][0].row) for i in used]) < config.min_group_span_px:
            return result("features_clustered", radius, len(good), len(used)), features, t1 - t0, t2 - t1
        used_displacements = np.array([records[i][4] for i in used])
        displacement = weighted_displacement(used_displacements, np.array([records[i][1].correlation for i in used]))
        sigma_m = displacement_standard_error(used_displacements, MATCH_PRECISION_PX * sample)
        return result("ok", radius, len(good), len(used), displacement, sigma_m), features, t1 - t0, t2 - t1

    def _uncertainty(self, pairs: list[PairResult], poses: list[geometry.CameraPose], times: np.ndarray) -> float:
        """Stated 1-sigma velocity uncertainty of a valid estimate (:func:`.solution.velocity_uncertainty`)."""
        config = self.config
        used = np.array([pair.valid for pair in pairs])
        biases = np.array([[pair.bias_east_mps, pair.bias_north_mps] for pair in pairs])[used]
        spread = float(np.linalg.norm(biases[:, None] - biases[None], axis=-1).max()) if len(biases) > 1 else 0.0
        heights = np.array([pose.centre_m[2] for pose in poses])
        reach = heights * (np.tan(np.array([pose.off_nadir_rad for pose in poses]))
                           + np.tan(0.5 * geometry.field_radius_rad(self.camera)))
        return velocity_uncertainty(heights, np.diff(times), used,
                                    np.array([pair.displacement_sigma_m for pair in pairs]), spread,
                                    config.attitude_uncertainty_rad / 3.0,
                                    config.relative_attitude_uncertainty_rad / 3.0,
                                    config.altitude_uncertainty_fraction / 3.0, reach)

    def _solve(self, pairs: list[PairResult]) -> tuple[bool, str, np.ndarray]:
        """Combine the pairs' bias estimates: (valid, reason, bias (2,) m/s)."""
        return combine_pairs(np.array([[p.bias_east_mps, p.bias_north_mps] for p in pairs]),
                             np.array([p.valid for p in pairs]), [p.reason for p in pairs],
                             self.config.pair_agreement_mps, self.config.require_both_pairs)


_CACHE: dict[tuple, tuple[Camera, EstimatorConfig, object, DimesEstimator]] = {}


def _flat_field_key(flat_field: np.ndarray | None) -> tuple[object, tuple]:
    """The array that owns a flat field's memory, and where in it the flat field lies.

    Two arrays with the same owner, data address, shape, strides and dtype are the same values (a campaign hands
    every case a fresh read-only view of one flat field: without this, each view would build a new estimator,
    ~5 ms a case). ``(None, ())`` for no flat field.
    """
    if flat_field is None:
        return None, ()
    array = np.asarray(flat_field)
    owner = array
    while isinstance(owner.base, np.ndarray):
        owner = owner.base
    return owner, (array.__array_interface__["data"][0], array.shape, array.strides, array.dtype.str)


def estimate_velocity(images: Sequence[np.ndarray], measurements: DescentMeasurements, camera: Camera,
                      config: EstimatorConfig = EstimatorConfig(),
                      flat_field: np.ndarray | None = None) -> VelocityEstimate:
    """:meth:`DimesEstimator.estimate` with the estimator cached per camera, config and flat field.

    Parameters
    ----------
    images : sequence of ndarray
        Raw images in time order (DN), shape ``camera.binned_shape``.
    measurements : DescentMeasurements
        Their measurements.
    camera : Camera
        The camera as designed.
    config : EstimatorConfig, optional
        The estimator's parameters.
    flat_field : ndarray or None, optional
        Measured flat field, shape ``camera.binned_shape``; cached by its memory: the same array, or a view of
        the same memory with the same shape, strides and dtype (e.g. a fresh read-only view per case).

    Returns
    -------
    VelocityEstimate
        As :meth:`DimesEstimator.estimate`.
    """
    owner, layout = _flat_field_key(flat_field)
    key = (id(camera), id(owner), layout)
    cached = _CACHE.get(key)
    if cached is None or cached[0] is not camera or cached[1] != config or cached[2] is not owner:
        if len(_CACHE) > 8:
            _CACHE.clear()
        cached = (camera, config, owner, DimesEstimator(camera, config, flat_field))
        _CACHE[key] = cached
    return cached[3].estimate(images, measurements)
