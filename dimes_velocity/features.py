"""Feature selection: corner-like templates on a coarse grid of a rectified image.

The interest of a template centred at a pixel is the smaller eigenvalue of the gradient structure
tensor summed over the template (Shi-Tomasi "good features to track", ``cv2.cornerMinEigenVal`` with
``blockSize`` = template size): it is large only when the template is textured in two directions,
which is what a 2-D correlation needs. The allowed centres (``candidates``) are split into a
``feature_grid x feature_grid`` grid over their bounding box; each cell offers its most interesting
centre, and the best offers with enough contrast (standard deviation of the template minus its
best-fit plane, over the expected pixel noise), at least ``min_feature_spacing_px`` apart, are
selected.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

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

    ``offered`` counts grid cells with an allowed centre; ``low_contrast`` those rejected for contrast.
    """

    features: tuple[Candidate, ...]
    offered: int
    low_contrast: int


def interest_map(image: np.ndarray, config: EstimatorConfig) -> np.ndarray:
    """Minimum eigenvalue of the gradient structure tensor over a template-sized block, float32."""
    return cv2.cornerMinEigenVal(image, blockSize=config.template_size_px, ksize=3)


def template_statistics(image: np.ndarray, column: int, row: int, half: int) -> tuple[float, float, float]:
    """Mean, standard deviation and detrended standard deviation of the (2 half + 1)^2 template at
    (column, row). The detrended value removes the best-fit plane: a smooth brightness ramp (the
    photometric function, the opposition halo's flank) has contrast but nothing to correlate on."""
    patch = image[row - half: row + half + 1, column - half: column + half + 1].astype(np.float64)
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    norm = (2 * half + 1) * float(offsets @ offsets)
    mean = float(patch.mean())
    slope_x = float((patch.sum(axis=0) @ offsets) / norm)
    slope_y = float((patch.sum(axis=1) @ offsets) / norm)
    residual = patch - mean - slope_x * offsets[None, :] - slope_y * offsets[:, None]
    return mean, float(patch.std()), float(residual.std())


class FeatureSelector:
    """Templates in decreasing interest, drawn one at a time (:meth:`next`): the contrast of an offer
    is measured only when it is drawn, so a pair whose first matches agree pays for no more.

    Parameters
    ----------
    image : ndarray float32 (N, N)
        Rectified, flattened image.
    candidates : ndarray bool (N, N)
        Where a template centre is allowed (template inside valid ground, search window inside B...).
    noise_dn_at : callable (column, row) -> float
        Expected pixel noise (DN) at a rectified position.
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
        if candidates.any():
            if interest is None:
                interest = interest_map(image, config)
            rows = np.flatnonzero(candidates.any(axis=1))
            columns = np.flatnonzero(candidates.any(axis=0))
            row_edges = np.linspace(rows[0], rows[-1] + 1, config.feature_grid + 1).astype(int)
            column_edges = np.linspace(columns[0], columns[-1] + 1, config.feature_grid + 1).astype(int)
            scored = np.where(candidates, interest, -1.0)
            for top, bottom in zip(row_edges[:-1], row_edges[1:]):
                for left, right in zip(column_edges[:-1], column_edges[1:]):
                    cell = scored[top:bottom, left:right]
                    if cell.size == 0:
                        continue
                    index = int(np.argmax(cell))
                    row, column = divmod(index, cell.shape[1])
                    if cell[row, column] < 0:
                        continue
                    self._offers.append((float(cell[row, column]), left + column, top + row))
            self._offers.sort(key=lambda offer: -offer[0])
        self.offered = len(self._offers)
        self._position = 0

    def next(self) -> Candidate | None:
        """The next template with enough contrast, at least ``min_feature_spacing_px`` from those drawn
        before; None when the offers are exhausted."""
        config = self.config
        half = config.template_size_px // 2
        spacing2 = config.min_feature_spacing_px ** 2
        while self._position < len(self._offers):
            score, column, row = self._offers[self._position]
            self._position += 1
            if any((column - c.column) ** 2 + (row - c.row) ** 2 < spacing2 for c in self.chosen):
                continue
            mean, std, detrended = template_statistics(self.image, column, row, half)
            noise = max(float(self.noise_dn_at(column, row)), 1e-6)
            if detrended / noise < config.min_contrast_to_noise:
                self.low_contrast += 1
                continue
            candidate = Candidate(column, row, score, mean, std, detrended / noise)
            self.chosen.append(candidate)
            return candidate
        return None


def select_features(image: np.ndarray, candidates: np.ndarray, noise_dn_at, config: EstimatorConfig,
                    interest: np.ndarray | None = None) -> Selection:
    """Pick up to ``config.features_per_pair`` templates at once (parameters as :class:`FeatureSelector`)."""
    selector = FeatureSelector(image, candidates, noise_dn_at, config, interest)
    while len(selector.chosen) < config.features_per_pair and selector.next() is not None:
        pass
    return Selection(tuple(selector.chosen), selector.offered, selector.low_contrast)
