"""Feature selection: corner-like templates on a coarse grid of a rectified image.

The interest of a template centred at a pixel is the smaller eigenvalue of the gradient structure
tensor summed over the template (Shi-Tomasi "good features to track", ``cv2.cornerMinEigenVal`` with
``blockSize`` = template size): it is large only when the template is textured in two directions,
which is what a 2-D correlation needs. The allowed centres (``candidates``) are split into a
``feature_grid x feature_grid`` grid over their bounding box; each cell offers its most interesting
centre, and the best offers with enough contrast (standard deviation of the template minus its
best-fit plane, over the expected pixel noise; and, when ``min_template_contrast_dn`` is set, a standard
deviation of at least that many DN), at least ``min_feature_spacing_px`` apart, are
selected. The interest is computed only over the candidates' bounding box grown by the operator's
reach (:func:`interest_window`): the same values as the whole-image map there.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from dimes_velocity import compiled
from dimes_velocity.config import EstimatorConfig


@dataclass(frozen=True)
class Candidate:
    """A selected template.

    Attributes
    ----------
    column, row : int
        Template centre in the rectified image.
    interest : float
        Minimum structure-tensor eigenvalue (DN^2 per pixel^2 summed over the template).
    brightness_dn : float
        Mean of the template (flattened DN).
    contrast_dn : float
        Standard deviation of the template (flattened DN).
    contrast_to_noise : float
        Detrended standard deviation (best-fit plane removed) over the expected pixel noise.
    """

    column: int
    row: int
    interest: float
    brightness_dn: float
    contrast_dn: float
    contrast_to_noise: float


@dataclass(frozen=True)
class Selection:
    """Selected templates, and why there are not more (for reason codes).

    Attributes
    ----------
    features : tuple of Candidate
        The selected templates, in the order drawn.
    offered : int
        Grid cells with an allowed centre.
    low_contrast : int
        Offers rejected for contrast.
    """

    features: tuple[Candidate, ...]
    offered: int
    low_contrast: int


def interest_map(image: np.ndarray, config: EstimatorConfig) -> np.ndarray:
    """Minimum eigenvalue of the gradient structure tensor over a template-sized block.

    Parameters
    ----------
    image : ndarray, shape (N, M), float32
        Rectified, flattened image (DN).
    config : EstimatorConfig
        The estimator's parameters (``template_size_px``).

    Returns
    -------
    ndarray, shape (N, M), float32
        The interest (DN^2 per pixel^2, summed over the block).
    """
    return cv2.cornerMinEigenVal(image, blockSize=config.template_size_px, ksize=3)


def interest_window(image: np.ndarray, config: EstimatorConfig, top: int, bottom: int, left: int,
                    right: int) -> np.ndarray:
    """:func:`interest_map` on rows ``top:bottom`` and columns ``left:right`` only, float32.

    Computed on the window grown by the operator's reach (``template_size_px // 2`` of the block plus
    1 of the 3 x 3 Sobel), clipped to the image: inside the window every value has the same support
    as in the whole-image map, and where the grown window meets the image edge it has the same border
    (OpenCV's filters sum in float64, exactly for these float32 products: the values are the same,
    tested against the whole-image map).

    Parameters
    ----------
    image : ndarray, shape (N, M), float32
        Rectified, flattened image (DN).
    config : EstimatorConfig
        The estimator's parameters (``template_size_px``).
    top, bottom : int
        Rows of the window, ``top:bottom``.
    left, right : int
        Columns of the window, ``left:right``.

    Returns
    -------
    ndarray, shape (bottom - top, right - left), float32
        The interest in the window.
    """
    reach = config.template_size_px // 2 + 1
    rows, columns = image.shape
    top_r, left_r = max(top - reach, 0), max(left - reach, 0)
    bottom_r, right_r = min(bottom + reach, rows), min(right + reach, columns)
    grown = cv2.cornerMinEigenVal(image[top_r:bottom_r, left_r:right_r], blockSize=config.template_size_px, ksize=3)
    return grown[top - top_r: bottom - top_r, left - left_r: right - left_r]


@lru_cache(maxsize=8)
def _plane_offsets(half: int) -> tuple[np.ndarray, float]:
    """Template offsets ``-half .. half`` (float64, read-only) and ``(2 half + 1) sum(offsets^2)``."""
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    offsets.setflags(write=False)
    return offsets, (2 * half + 1) * float(offsets @ offsets)


def template_statistics(image: np.ndarray, column: int, row: int, half: int) -> tuple[float, float, float]:
    """Mean, standard deviation and detrended standard deviation of a template.

    The detrended value removes the best-fit plane: a smooth brightness ramp (the photometric
    function, the opposition halo's flank) has contrast but nothing to correlate on. The same float64
    reductions as ``patch.mean()`` and ``patch.std()`` (numpy's pairwise sums), with the template's
    deviations from its mean shared by the standard deviation and the plane fit.

    Parameters
    ----------
    image : ndarray, shape (N, M)
        Rectified, flattened image (DN).
    column, row : int
        Template centre (px); the template lies inside the image.
    half : int
        Half size: the template is (2 half + 1) x (2 half + 1) pixels.

    Returns
    -------
    mean_dn, std_dn, detrended_std_dn : float
        The three statistics (DN).
    """
    patch = image[row - half: row + half + 1, column - half: column + half + 1].astype(np.float64)
    offsets, norm = _plane_offsets(half)
    count = patch.size
    mean = float(np.add.reduce(patch, axis=None)) / count
    slope_x = float((patch.sum(axis=0) @ offsets) / norm)
    slope_y = float((patch.sum(axis=1) @ offsets) / norm)
    centred = patch - mean
    std = float(np.sqrt(np.add.reduce(centred * centred, axis=None) / count))
    residual = centred - slope_x * offsets[None, :]
    residual -= slope_y * offsets[:, None]
    residual -= float(np.add.reduce(residual, axis=None)) / count
    residual *= residual
    return mean, std, float(np.sqrt(np.add.reduce(residual, axis=None) / count))


def templates_statistics(image: np.ndarray, centres: list[tuple[int, int]],
                         half: int) -> list[tuple[float, float, float]]:
    """:func:`template_statistics` of several templates, in one compiled call.

    The same values: :func:`compiled.templates_statistics` makes the same float64 operations on each template as
    :func:`template_statistics` (numpy's pairwise sums, the column sums down the rows, the slopes' dot products).

    Parameters
    ----------
    image : ndarray, shape (N, M)
        Rectified, flattened image (DN).
    centres : list of (int, int)
        Template centres ``(column, row)`` (px); every template lies inside the image.
    half : int
        Half size: the templates are (2 half + 1) x (2 half + 1) pixels.

    Returns
    -------
    list of (mean_dn, std_dn, detrended_std_dn)
        Per template, as :func:`template_statistics`.
    """
    if not centres:
        return []
    offsets, norm = _plane_offsets(half)
    columns = np.array([column for column, _ in centres], dtype=np.int64)
    rows = np.array([row for _, row in centres], dtype=np.int64)
    statistics = compiled.templates_statistics(np.asarray(image), columns, rows, half, offsets, norm)
    return [(mean, std, detrended) for mean, std, detrended in statistics.tolist()]


_STATISTICS_BATCH = 4       # offers whose contrast is measured together (a pair often stops after the first four)


def _edges(start: int, stop: int, cells: int) -> list[int]:
    """``np.linspace(start, stop, cells + 1).astype(int)`` (the same float64 steps) as Python ints."""
    step = (stop - start) / cells
    return [int(i * step + start) for i in range(cells)] + [int(stop)]


class FeatureSelector:
    """Templates in decreasing interest, drawn one at a time (:meth:`next`).

    The contrast of the offers is measured as they are drawn: four at a time (a pair whose first matches agree pays
    for no more), after eight all the others at once (:func:`templates_statistics`, the same values as one at a
    time).

    Parameters
    ----------
    image : ndarray float32 (N, N)
        Rectified, flattened image.
    candidates : ndarray bool (N, N)
        Where a template centre is allowed (template inside valid ground, search window inside B...).
    noise_dn_at : callable (column, row) -> float
        Expected pixel noise (DN) at a rectified position.
    config : EstimatorConfig
        The estimator's parameters (template size, grid, spacing, contrast).
    interest : ndarray, optional
        Precomputed :func:`interest_map` of ``image``.

    Attributes
    ----------
    offered : int
        Grid cells with an allowed centre.
    low_contrast : int
        Offers drawn and refused for contrast so far.
    """

    def __init__(self, image: np.ndarray, candidates: np.ndarray, noise_dn_at, config: EstimatorConfig,
                 interest: np.ndarray | None = None):
        self.image, self.noise_dn_at, self.config = image, noise_dn_at, config
        self.chosen: list[Candidate] = []
        self.low_contrast = 0
        self._offers: list[tuple[float, int, int]] = []
        rows = np.flatnonzero(candidates.any(axis=1))
        if len(rows):
            columns = np.flatnonzero(candidates.any(axis=0))
            top, bottom, left, right = int(rows[0]), int(rows[-1]) + 1, int(columns[0]), int(columns[-1]) + 1
            if interest is None:           # only where a centre may be: the candidates' bounding box
                interest = interest_window(image, config, top, bottom, left, right)
            else:
                interest = interest[top:bottom, left:right]
            # each grid cell's best allowed pixel (compiled: argmax of np.where(candidates, interest, -1) per cell)
            row_edges = np.array(_edges(top, bottom, config.feature_grid)) - top
            column_edges = np.array(_edges(left, right, config.feature_grid)) - left
            scores, columns, rows = compiled.grid_maxima(np.ascontiguousarray(interest, dtype=np.float32),
                                                         np.ascontiguousarray(candidates[top:bottom, left:right]),
                                                         row_edges, column_edges)
            self._offers = [(score, left + column, top + row)
                            for score, column, row in zip(scores.tolist(), columns.tolist(), rows.tolist())]
            self._offers.sort(key=lambda offer: -offer[0])
        self.offered = len(self._offers)
        self._position = 0
        self._statistics: list[tuple[float, float, float]] = []     # of the offers measured so far, in order

    def next(self) -> Candidate | None:
        """The next template with enough contrast, at least ``min_feature_spacing_px`` from those drawn before.

        Returns
        -------
        Candidate or None
            The template; None when the offers are exhausted.
        """
        config = self.config
        half = config.template_size_px // 2
        spacing2 = config.min_feature_spacing_px ** 2
        while self._position < len(self._offers):
            score, column, row = self._offers[self._position]
            self._position += 1
            if any((column - c.column) ** 2 + (row - c.row) ** 2 < spacing2 for c in self.chosen):
                continue
            index = self._position - 1
            if index >= len(self._statistics):      # measure the next few offers at once: 4, 4 more, then the rest
                done = len(self._statistics)
                stop = done + _STATISTICS_BATCH if done < 2 * _STATISTICS_BATCH else len(self._offers)
                self._statistics += templates_statistics(
                    self.image, [(c, r) for _, c, r in self._offers[len(self._statistics): max(stop, index + 1)]],
                    half)
            mean, std, detrended = self._statistics[index]
            noise = max(float(self.noise_dn_at(column, row)), 1e-6)
            if detrended / noise < config.min_contrast_to_noise or std < config.min_template_contrast_dn:
                self.low_contrast += 1
                continue
            candidate = Candidate(column, row, score, mean, std, detrended / noise)
            self.chosen.append(candidate)
            return candidate
        return None


def select_features(image: np.ndarray, candidates: np.ndarray, noise_dn_at, config: EstimatorConfig,
                    interest: np.ndarray | None = None) -> Selection:
    """Pick up to ``config.features_per_pair`` templates at once.

    Parameters
    ----------
    image : ndarray, shape (N, N), float32
        Rectified, flattened image.
    candidates : ndarray of bool, shape (N, N)
        Where a template centre is allowed.
    noise_dn_at : callable
        ``(column, row) -> float``: expected pixel noise (DN) at a rectified position.
    config : EstimatorConfig
        The estimator's parameters.
    interest : ndarray, optional
        Precomputed :func:`interest_map` of ``image``.

    Returns
    -------
    Selection
        The templates and the counts behind the reason codes.
    """
    selector = FeatureSelector(image, candidates, noise_dn_at, config, interest)
    while len(selector.chosen) < config.features_per_pair and selector.next() is not None:
        pass
    return Selection(tuple(selector.chosen), selector.offered, selector.low_contrast)
