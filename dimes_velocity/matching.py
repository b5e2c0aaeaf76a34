"""Template matching: two-level pyramid, normalised correlation, sub-pixel peak, quality measures.

A template from rectified image A is searched for in rectified image B around a predicted position:

1. coarse level (``cv2.pyrDown`` of both images, half resolution): a ``coarse_template_size_px``
   template (twice the ground extent of the fine one) is correlated over the whole search window
   (``cv2.matchTemplate``, ``TM_CCOEFF_NORMED``); this is where the search is done, so this is where
   the peak must be distinct: no displacement outside the best peak's own lobe may correlate within
   ``k sigma`` of the best, ``sigma`` the noise of a difference of two correlations from the pixel
   noise of the two images and ``k = ambiguity_confidence_sigma`` (:func:`distinct_peak_level`): the
   part of the surface at or above ``best - k sigma`` must be one connected region (:func:`lobes_above`),
   so the lobe is as wide as the template's autocorrelation and the noise make it; optionally (off by
   default) the highest other local maximum (further than ``second_peak_exclusion_px`` from the best)
   must also be below ``max_second_peak_ratio`` of the best. The best peak's smallest principal
   curvature (biquadratic fit, 1 / coarse px^2) must be at least ``min_coarse_peak_curvature`` (a ridge,
   as along dune crests, has one curvature near zero);
2. fine level: the ``template_size_px`` template is correlated within ``fine_search_radius_px`` of
   twice the coarse peak;
3. sub-pixel: a biquadratic ``z = a + b x + c y + d x^2 + e x y + f y^2`` is fitted (least squares)
   to the 3 x 3 correlation values around the peak; its maximum is the sub-pixel offset and its
   Hessian the peak sharpness. The fit is biased (the correlation surface is not symmetric about
   its peak, and a parabola "locks" toward integer positions: errors up to ~0.1 px), so the offset
   is then refined by up to ``subpixel_iterations`` inverse-compositional Gauss-Newton
   (Lucas-Kanade) steps that match the normalised template to bicubically re-sampled, normalised B;
   the reported correlation is the normalised correlation at the refined position, which must
   reach ``min_correlation``, with a fine-level curvature of at least ``min_peak_curvature``;
4. the prior: the match must lie within the search radius (the prior's uncertainty bound, a
   circle) of the prediction.

Positions are ``(column, row)`` of template centres.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from dimes_velocity import compiled
from dimes_velocity.config import EstimatorConfig

_OFFSETS = np.array([(x, y) for y in (-1, 0, 1) for x in (-1, 0, 1)], dtype=float)
_DESIGN = np.column_stack([np.ones(9), _OFFSETS[:, 0], _OFFSETS[:, 1], _OFFSETS[:, 0] ** 2,
                           _OFFSETS[:, 0] * _OFFSETS[:, 1], _OFFSETS[:, 1] ** 2])
_FIT = np.linalg.pinv(_DESIGN)   # (6, 9): biquadratic coefficients from a raveled 3 x 3 patch


@dataclass(frozen=True)
class Match:
    """Outcome of one template search.

    Attributes
    ----------
    status : str
        "ok", or why the match was rejected, in the order tested: "search_outside" (window leaves
        the image), "search_border" (best peak on the edge of the search window), "ambiguous_match"
        (coarse level: another displacement not significantly worse than the best, or a second peak above
        ``max_second_peak_ratio`` of it), "flat_peak" (coarse or fine peak not
        sharp enough), "outside_prior" (the match lies further from the prediction than the prior's
        uncertainty radius), "low_correlation".
    position_px : ndarray (2,)
        Sub-pixel template centre in image B (column, row); the prediction when not found.
    correlation : float
        Normalised correlation at the fine-level peak (-1 .. 1).
    second_peak_ratio : float
        Second coarse peak / best coarse peak (1 when undefined).
    curvature_per_px2 : float
        Smallest principal curvature of the fitted fine peak (>= 0; 0 when not a maximum), 1/px^2.
    coarse_curvature_per_px2 : float
        The same at the coarse level, where the search is done (1 / coarse px^2).
    """

    status: str
    position_px: np.ndarray
    correlation: float
    second_peak_ratio: float
    curvature_per_px2: float
    coarse_curvature_per_px2: float = 0.0


def _correlate(window: np.ndarray, template: np.ndarray) -> np.ndarray:
    result = cv2.matchTemplate(window, template, cv2.TM_CCOEFF_NORMED)
    if not cv2.checkRange(result):          # NaN or infinite: flat window or template
        result = np.nan_to_num(result, nan=0.0, posinf=0.0, neginf=0.0)
    return result


def _crop(image: np.ndarray, column: int, row: int, half: int) -> np.ndarray | None:
    """The (2 half + 1)^2 square centred at (column, row), or None when it leaves the image."""
    if row - half < 0 or column - half < 0 or row + half >= image.shape[0] or column + half >= image.shape[1]:
        return None
    return image[row - half: row + half + 1, column - half: column + half + 1]


def second_peak(surface: np.ndarray, best: tuple[int, int], exclusion_px: int) -> float:
    """Highest local maximum (3 x 3 neighbourhood) of ``surface`` away from the best peak.

    Points on the flanks of a broad main peak are not local maxima, so they do not count as a second
    peak.

    Parameters
    ----------
    surface : ndarray, shape (rows, columns), float32
        Correlation surface.
    best : tuple of int
        (column, row) of the best peak.
    exclusion_px : int
        Maxima within this many pixels of ``best`` in both directions are ignored.

    Returns
    -------
    float
        The second peak's value; -1 when there is none.
    """
    column, row = best
    return float(compiled.second_peak(np.asarray(surface, dtype=np.float32), int(column), int(row), int(exclusion_px)))


def _variance(values: np.ndarray) -> float:
    """Population variance of a 2-D array (float64): ``np.var(values, dtype=np.float64)`` (:func:`compiled.variance`).

    The same float64 operations as numpy's ``var`` (sum to the mean, divide, subtract, square, sum, divide).
    """
    return float(compiled.variance(values))


def correlation_difference_sigma(best: float, other: float, template_variance: float, window_variance: float,
                                 noise_a_dn: float, noise_b_dn: float, pixels: int) -> float:
    """Standard deviation (upper bound) of ``best - other``, two coarse correlations of one template, from pixel noise.

    ``sqrt((eps_A^2 + eps_B^2) / N) (sqrt(1 - best^2) + sqrt(1 - other^2))``, the derivation and the noise terms
    ``eps`` in :func:`distinct_peak_level`.

    Parameters
    ----------
    best, other : float
        The two correlations (best peak ``rho0``, other displacement ``rho1``).
    template_variance, window_variance : float
        Variances of the coarse template and of the coarse window of B at the best peak (DN^2).
    noise_a_dn, noise_b_dn : float
        Fine-level pixel noise standard deviations of A and B (DN).
    pixels : int
        Pixels of the coarse template ``N``.

    Returns
    -------
    float
        The standard deviation (correlation units).
    """
    rho0 = min(max(float(best), -1.0), 1.0)
    rho1 = min(max(float(other), -1.0), 1.0)
    eps_a2 = 0.25 * noise_a_dn * noise_a_dn / max(template_variance, 1e-12)
    eps_b2 = max(0.25 * noise_b_dn * noise_b_dn / max(window_variance, 1e-12), 2.0 * (1.0 - rho0) - eps_a2)
    return math.sqrt((eps_a2 + eps_b2) / pixels) * (math.sqrt(max(1.0 - rho0 * rho0, 0.0))
                                                     + math.sqrt(max(1.0 - rho1 * rho1, 0.0)))


def distinct_peak_level(best: float, template_variance: float, window_variance: float, noise_a_dn: float,
                        noise_b_dn: float, pixels: int, confidence_sigma: float) -> float:
    """Correlation above which another displacement is not significantly worse than the best peak.

    The coarse correlation ``rho(d)`` of template ``t`` (image A, ``N`` pixels) with the window ``b(d)`` of
    image B changes with the pixel noise, to first order (delta method; ``^`` = normalised to zero mean and
    unit variance, ``eps^2`` = noise variance / template variance)::

        d rho = (1/N) sum_i [ eps_A n_Ai (b^_i - rho t^_i) + eps_B n_Bi (t^_i - rho b^_i) ],  n ~ N(0, 1)

    and since ``mean((b^ - rho t^)^2) = mean((t^ - rho b^)^2) = 1 - rho^2``, the difference ``rho0 - rho1``
    between the best peak and another displacement (their noise shared or not) has a standard deviation of at
    most::

        sigma(rho1) = sqrt((eps_A^2 + eps_B^2) / N) (sqrt(1 - rho0^2) + sqrt(1 - rho1^2))

    Pixel noise: ``noise_a_dn`` and ``noise_b_dn`` (fine pixels, taken as white), seen at the coarse level as
    white noise of variance ``noise^2 / 4`` per coarse pixel, an upper bound (``cv2.pyrDown``'s 5-tap binomial
    passes at most 1/2 of the noise power per axis, all of it at zero frequency). Decorrelation at the best
    peak beyond what the noise explains (resampling, rectification, rotation: ``1 - rho0 ~ (eps_A^2 +
    eps_B^2) / 2``) is counted as noise of B: ``eps_B^2 = max(model, 2 (1 - rho0) - eps_A^2)``. The level is
    ``L = rho0 - k sigma(L)`` (``k = confidence_sigma``, solved by fixed-point iteration).

    Parameters
    ----------
    best : float
        Best coarse correlation ``rho0``.
    template_variance, window_variance : float
        Variances of the coarse template and of the coarse window of B at the best peak (DN^2).
    noise_a_dn, noise_b_dn : float
        Fine-level pixel noise standard deviations of A and B (DN).
    pixels : int
        Pixels of the coarse template ``N``.
    confidence_sigma : float
        ``k``: how many standard deviations below the best a peak must lie to be distinct from it.

    Returns
    -------
    float
        The level ``L`` (-1 when nothing can be told apart).
    """
    return float(compiled.distinct_peak_level(float(best), float(template_variance), float(window_variance),
                                              float(noise_a_dn), float(noise_b_dn), int(pixels),
                                              float(confidence_sigma)))


def lobes_above(surface: np.ndarray, level: float) -> int:
    """Number of separate (8-connected) regions of ``surface >= level``.

    Parameters
    ----------
    surface : ndarray, shape (rows, columns), float32
        Correlation surface.
    level : float
        The level.

    Returns
    -------
    int
        Regions; 1 when only the best peak's own lobe reaches the level.
    """
    return int(compiled.lobes_above(surface, np.float32(level)))     # float32 >= a Python float: at float32


def fit_peak(patch: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Biquadratic fit to a 3 x 3 correlation patch centred on its maximum.

    Parameters
    ----------
    patch : ndarray, shape (3, 3)
        Correlation values around the maximum.

    Returns
    -------
    offset : ndarray (2,)
        Sub-pixel (column, row) position of the maximum relative to the centre, clipped to +-1.
    peak_value : float
        Fitted value at the maximum (clipped to [-1, 1]).
    curvature : float
        Smallest principal curvature ``min(-eig(Hessian))`` (0 when the surface is not a maximum).
    """
    x, y, value, curvature = compiled.fit_peak(_FIT, np.asarray(patch))
    return np.array([x, y]), value, curvature


def shift_window(window: np.ndarray, offset: np.ndarray, out_size: int) -> np.ndarray:
    """Sample a square ``window`` at ``(x + offset_x, y + offset_y)`` by Keys cubic convolution.

    Exact in sub-pixel position (no fixed-point quantisation of the coordinates, unlike
    ``cv2.warpAffine`` of OpenCV 4.x, which rounds to 1/32 pixel).

    Parameters
    ----------
    window : ndarray, shape (M, M)
        The image window; it must extend ``|offset| + 2`` pixels beyond the output on every side.
    offset : ndarray, shape (2,)
        (x, y) shift (px).
    out_size : int
        Side of the output square (px).

    Returns
    -------
    ndarray, shape (out_size, out_size), float64
        The central square, shifted.
    """
    return compiled.shifted_window(np.ascontiguousarray(window, dtype=np.float64), float(offset[0]), float(offset[1]),
                                   int(out_size))


def match_template(a_fine: np.ndarray, b_fine: np.ndarray, a_coarse: np.ndarray, b_coarse: np.ndarray,
                   centre_a: tuple[int, int], predicted_b: np.ndarray, search_radius_px: float,
                   config: EstimatorConfig, noise_a_dn: float = 0.0, noise_b_dn: float = 0.0) -> Match:
    """Find the template of A centred at ``centre_a`` in B near ``predicted_b`` (module docstring).

    Parameters
    ----------
    a_fine, b_fine : ndarray, shape (N, N), float32
        The pair's rectified, flattened images.
    a_coarse, b_coarse : ndarray, shape (N / 2, N / 2), float32
        The same at half resolution (``cv2.pyrDown``).
    centre_a : tuple of int
        (column, row) of the template in A (fine px).
    predicted_b : ndarray, shape (2,)
        IMU-predicted (column, row) of the template in B (fine px).
    search_radius_px : float
        Radius of the search around the prediction (fine px).
    config : EstimatorConfig
        Template sizes and the acceptance thresholds.
    noise_a_dn, noise_b_dn : float, optional
        Expected pixel noise standard deviation (DN) of the fine images around the template and around the
        prediction, for the distinct-peak test (:func:`distinct_peak_level`); 0: noise-free.

    Returns
    -------
    Match
        The match's position in B, correlation and peak shape, and its status (``"ok"`` or why not).
    """
    predicted_b = np.asarray(predicted_b, dtype=float)
    u, v = int(centre_a[0]), int(centre_a[1])
    half_c = config.coarse_template_size_px // 2
    half_f = config.template_size_px // 2

    def failed(status: str, correlation: float = 0.0, ratio: float = 1.0, coarse_curvature: float = 0.0) -> Match:
        return Match(status, predicted_b.copy(), float(correlation), float(ratio), 0.0, float(coarse_curvature))

    # coarse level: the search over the whole window, so the distinct-peak tests are made here
    # (positions as Python ints; round() rounds half to even, as np.rint)
    parity_u, parity_v = u % 2, v % 2
    template_c = _crop(a_coarse, u // 2, v // 2, half_c)
    radius_c = math.ceil(search_radius_px / 2.0) + 1
    centre_cu = round((float(predicted_b[0]) - parity_u) / 2.0)
    centre_cv = round((float(predicted_b[1]) - parity_v) / 2.0)
    window_c = _crop(b_coarse, centre_cu, centre_cv, half_c + radius_c)
    if template_c is None or window_c is None:
        return failed("search_outside")
    surface = _correlate(window_c, template_c)
    best, i_col, i_row, second = compiled.peak_and_second(surface, config.second_peak_exclusion_px)
    ratio = min(max(second / best, -1.0), 1.0) if best > 1e-6 else 1.0
    last = surface.shape[0] - 1
    if i_row in (0, last) or i_col in (0, last):
        return failed("search_border", best, ratio)
    _, _, coarse_curvature = fit_peak(surface[i_row - 1: i_row + 2, i_col - 1: i_col + 2])
    if ratio > config.max_second_peak_ratio:
        return failed("ambiguous_match", best, ratio, coarse_curvature)
    if config.ambiguity_confidence_sigma > 0.0:
        window_at_best = window_c[i_row: i_row + template_c.shape[0], i_col: i_col + template_c.shape[1]]
        level = distinct_peak_level(best, _variance(template_c), _variance(window_at_best), noise_a_dn, noise_b_dn,
                                    template_c.size, config.ambiguity_confidence_sigma)
        if lobes_above(surface, level) > 1:
            return failed("ambiguous_match", best, ratio, coarse_curvature)
    if coarse_curvature < config.min_coarse_peak_curvature:
        return failed("flat_peak", best, ratio, coarse_curvature)

    # fine level (re-centred at most twice when the peak sits on the window's edge)
    template_f = _crop(a_fine, u, v, half_f)
    guess_u = 2 * (centre_cu - radius_c + i_col) + parity_u
    guess_v = 2 * (centre_cv - radius_c + i_row) + parity_v
    radius_f = config.fine_search_radius_px
    for _ in range(3):
        window_f = _crop(b_fine, guess_u, guess_v, half_f + radius_f)
        if template_f is None or window_f is None:
            return failed("search_outside", best, ratio, coarse_curvature)
        fine = _correlate(window_f, template_f)
        _, _, _, (j_col, j_row) = cv2.minMaxLoc(fine)
        step_u, step_v = j_col - radius_f, j_row - radius_f
        guess_u, guess_v = guess_u + step_u, guess_v + step_v
        if abs(step_u) < radius_f and abs(step_v) < radius_f:
            break
    else:
        return failed("search_border", best, ratio, coarse_curvature)
    offset, correlation, curvature = fit_peak(fine[j_row - 1: j_row + 2, j_col - 1: j_col + 2])
    if config.subpixel_iterations > 0:
        refined_x, refined_y, value = compiled.refine(a_fine, b_fine, u, v, guess_u, guess_v, float(offset[0]),
                                                      float(offset[1]), half_f, config.subpixel_iterations)
        if math.isfinite(value):
            offset, correlation = np.array([refined_x, refined_y]), value
    position = np.array([guess_u + offset[0], guess_v + offset[1]], dtype=float)
    if curvature < config.min_peak_curvature:
        status = "flat_peak"
    elif float(np.hypot(position[0] - predicted_b[0], position[1] - predicted_b[1])) > search_radius_px:
        status = "outside_prior"
    elif correlation < config.min_correlation:
        status = "low_correlation"
    else:
        status = "ok"
    return Match(status, position, float(correlation), ratio, float(curvature), float(coarse_curvature))
