"""The matcher's compiled (numba) passes against their definitions written out in numpy: the same bits.

The definitions are the numpy code the kernels replaced (numpy's pairwise sums, BLAS dot products, the
element-wise passes in the same order); the kernels must give exactly their values, so that the estimates do
not move.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from dimes_velocity import compiled
from dimes_velocity.matching import _FIT, distinct_peak_level, fit_peak, shift_window


def _keys_weights(fraction: float) -> tuple[float, float, float, float]:
    t = float(fraction)
    return (((-0.5 * t + 1.0) * t - 0.5) * t, (1.5 * t - 2.5) * t * t + 1.0, ((-1.5 * t + 2.0) * t + 0.5) * t,
            (0.5 * t - 0.5) * t * t)


def _shifted_window(window, offset_x, offset_y, out_size):
    """Keys re-sampling, horizontal then vertical pass, sums left to right into one buffer (numpy)."""
    first_out = window.shape[0] // 2 - out_size // 2
    whole_x, whole_y = math.floor(offset_x), math.floor(offset_y)
    wx, wy = _keys_weights(offset_x - whole_x), _keys_weights(offset_y - whole_y)
    fx, fy = first_out + whole_x - 1, first_out + whole_y - 1
    rows = window[fy: fy + out_size + 3]
    columns = np.multiply(rows[:, fx: fx + out_size], wx[0])
    term = np.empty_like(columns)
    for k in (1, 2, 3):
        columns += np.multiply(rows[:, fx + k: fx + k + out_size], wx[k], out=term)
    out = np.multiply(columns[0:out_size], wy[0])
    term = term[:out_size]
    for k in (1, 2, 3):
        out += np.multiply(columns[k: k + out_size], wy[k], out=term)
    return out


def _crop(image, column, row, half):
    if row - half < 0 or column - half < 0 or row + half >= image.shape[0] or column + half >= image.shape[1]:
        return None
    return image[row - half: row + half + 1, column - half: column + half + 1]


def _clip(value, bound):
    return -bound if value < -bound else bound if value > bound else value


def _refine(image_a, image_b, centre_a, peak, offset, half, iterations):
    """Inverse-compositional Gauss-Newton refinement written out in numpy: (offset, correlation)."""
    window = _crop(image_b, int(peak[0]), int(peak[1]), half + 4)
    padded = _crop(image_a, int(centre_a[0]), int(centre_a[1]), half + 1)
    if window is None or padded is None:
        return offset, float("nan")
    window = window.astype(np.float64)
    padded = padded.astype(np.float64)
    template = padded[1:-1, 1:-1].ravel()
    count = template.size
    centred = template - float(np.add.reduce(template)) / count
    spread = float(np.sqrt(np.dot(centred, centred) / count))
    if not spread > 0:
        return offset, float("nan")
    target = centred / spread
    grad_x = ((0.5 / spread) * (padded[1:-1, 2:] - padded[1:-1, :-2])).ravel()
    grad_y = ((0.5 / spread) * (padded[2:, 1:-1] - padded[:-2, 1:-1])).ravel()
    hxx, hxy, hyy = np.dot(grad_x, grad_x), np.dot(grad_x, grad_y), np.dot(grad_y, grad_y)
    determinant = hxx * hyy - hxy * hxy
    if not determinant > 1e-12 * max(hxx * hyy, 1e-300):
        return offset, float("nan")
    size = 2 * half + 1

    def normalised_at(shift_x, shift_y):
        moved = _shifted_window(window, shift_x, shift_y, size).ravel()
        moved -= float(np.add.reduce(moved)) / count
        norm = float(np.sqrt(np.dot(moved, moved) / count))
        return np.divide(moved, norm, out=moved) if norm > 0 else None

    offset_x, offset_y = float(offset[0]), float(offset[1])
    correlation = float("nan")
    for step in range(iterations + 1):
        normalised = normalised_at(offset_x, offset_y)
        if normalised is None:
            return np.array([offset_x, offset_y]), float("nan")
        correlation = float(np.dot(normalised, target)) / count
        if step == iterations:
            break
        error = np.subtract(normalised, target, out=normalised)
        ex, ey = np.dot(grad_x, error), np.dot(grad_y, error)
        delta_x, delta_y = (hyy * ex - hxy * ey) / determinant, (hxx * ey - hxy * ex) / determinant
        offset_x, offset_y = _clip(offset_x - delta_x, 1.5), _clip(offset_y - delta_y, 1.5)
        if max(abs(delta_x), abs(delta_y)) < 1e-3:
            normalised = normalised_at(offset_x, offset_y)
            if normalised is not None:
                correlation = float(np.dot(normalised, target)) / count
            break
    return np.array([offset_x, offset_y]), correlation


def _fit_peak(patch):
    a, bx, by, dxx, exy, fyy = (_FIT @ patch.astype(float).ravel()).tolist()
    hxx, hxy, hyy = 2.0 * dxx, exy, 2.0 * fyy
    larger = 0.5 * (hxx + hyy) + float(np.hypot(0.5 * (hxx - hyy), hxy))
    if larger < 0.0:
        determinant = hxx * hyy - hxy * hxy
        x = (-bx * hyy + by * hxy) / determinant
        y = (-by * hxx + bx * hxy) / determinant
        curvature = -larger
    else:
        x = -bx / hxx if hxx < 0 else 0.0
        y = -by / hyy if hyy < 0 else 0.0
        curvature = 0.0
    x, y = min(max(x, -1.0), 1.0), min(max(y, -1.0), 1.0)
    value = a + bx * x + by * y + dxx * x * x + exy * x * y + fyy * y * y
    return np.array([x, y]), min(max(value, -1.0), 1.0), curvature


def _difference_sigma(best, other, template_variance, window_variance, noise_a_dn, noise_b_dn, pixels):
    rho0 = min(max(float(best), -1.0), 1.0)
    rho1 = min(max(float(other), -1.0), 1.0)
    eps_a2 = 0.25 * noise_a_dn * noise_a_dn / max(template_variance, 1e-12)
    eps_b2 = max(0.25 * noise_b_dn * noise_b_dn / max(window_variance, 1e-12), 2.0 * (1.0 - rho0) - eps_a2)
    return math.sqrt((eps_a2 + eps_b2) / pixels) * (math.sqrt(max(1.0 - rho0 * rho0, 0.0))
                                                     + math.sqrt(max(1.0 - rho1 * rho1, 0.0)))


def _distinct_peak_level(best, template_variance, window_variance, noise_a_dn, noise_b_dn, pixels, confidence_sigma):
    rho0 = min(max(float(best), -1.0), 1.0)
    level = rho0
    for _ in range(8):
        updated = rho0 - confidence_sigma * _difference_sigma(rho0, level, template_variance, window_variance,
                                                              noise_a_dn, noise_b_dn, pixels)
        if updated <= -1.0:
            return -1.0
        if abs(updated - level) < 1e-6:
            return updated
        level = updated
    return level


@pytest.mark.parametrize("count", [0, 1, 7, 8, 9, 121, 128, 129, 225, 256, 1000, 4097])
def test_pairwise_sum_is_numpys(count):
    rng = np.random.default_rng(count)
    for _ in range(50):
        values = rng.standard_normal(count) * 10.0 ** rng.uniform(-6, 6, count)
        assert compiled.pairwise_sum(values, 0, count) == np.add.reduce(values)
    values = rng.standard_normal(count + 5)
    assert compiled.pairwise_sum(values, 3, count) == np.add.reduce(values[3:3 + count])


def test_shifted_window_is_its_definition():
    rng = np.random.default_rng(3)
    window = rng.uniform(0.0, 400.0, (23, 23))
    for offset in rng.uniform(-1.5, 1.5, (200, 2)).tolist() + [[0.0, 0.0], [-1.5, 1.5], [1.0, -1.0]]:
        assert np.array_equal(shift_window(window, np.array(offset), 15), _shifted_window(window, *offset, 15))


def _textured_pair(seed, shift, size=64):
    """A smooth random texture and the same texture moved by ``shift`` (px), float32, with noise."""
    rng = np.random.default_rng(seed)
    rows, columns = np.mgrid[0:size, 0:size].astype(np.float64)
    image_a, image_b = np.zeros((size, size)), np.zeros((size, size))
    for _ in range(12):
        kx, ky, phase, amplitude = rng.uniform(0.1, 0.6), rng.uniform(0.1, 0.6), rng.uniform(0, 6.3), rng.uniform(5, 30)
        image_a += amplitude * np.sin(kx * columns + ky * rows + phase)
        image_b += amplitude * np.sin(kx * (columns - shift[0]) + ky * (rows - shift[1]) + phase)
    noise = rng.standard_normal((2, size, size))
    return (200.0 + image_a + noise[0]).astype(np.float32), (200.0 + image_b + noise[1]).astype(np.float32)


@pytest.mark.parametrize("seed", range(12))
def test_refine_is_its_definition(seed):
    rng = np.random.default_rng(100 + seed)
    shift = rng.uniform(-0.6, 0.6, 2)
    image_a, image_b = _textured_pair(seed, shift)
    offset = rng.uniform(-1.0, 1.0, 2)
    for centre, iterations in (((30, 31), 2), ((25, 40), 0), ((40, 22), 5), ((8, 30), 2), ((60, 30), 2)):
        peak = (centre[0] + int(round(shift[0])), centre[1] + int(round(shift[1])))
        want_offset, want_correlation = _refine(image_a, image_b, centre, peak, offset, 7, iterations)
        got_x, got_y, got_correlation = compiled.refine(image_a, image_b, centre[0], centre[1], peak[0], peak[1],
                                                        float(offset[0]), float(offset[1]), 7, iterations)
        assert (got_x, got_y) == tuple(float(value) for value in want_offset)
        assert got_correlation == want_correlation or (math.isnan(got_correlation) and math.isnan(want_correlation))
        if centre == (30, 31):                  # inside both images: a real refinement, not the NaN exit
            assert got_correlation > 0.9


def test_refine_of_a_flat_template_is_nan_as_its_definition():
    image_a = np.full((40, 40), 7.0, np.float32)
    _, image_b = _textured_pair(1, (0.2, 0.1), 40)
    got = compiled.refine(image_a, image_b, 20, 20, 20, 20, 0.25, -0.5, 7, 2)
    want_offset, want_correlation = _refine(image_a, image_b, (20, 20), (20, 20), np.array([0.25, -0.5]), 7, 2)
    assert got[:2] == (0.25, -0.5) and tuple(want_offset) == (0.25, -0.5)
    assert math.isnan(got[2]) and math.isnan(want_correlation)


def test_fit_peak_is_its_definition():
    rng = np.random.default_rng(7)
    patches = [rng.uniform(-1.0, 1.0, (3, 3)).astype(np.float32) for _ in range(300)]
    rows, columns = np.mgrid[-1:2, -1:2]
    patches += [(0.9 - 0.1 * (columns - x) ** 2 - 0.2 * (rows - y) ** 2).astype(np.float32)
                for x, y in rng.uniform(-0.7, 0.7, (100, 2))]
    for patch in patches:
        got_offset, got_value, got_curvature = fit_peak(patch)
        want_offset, want_value, want_curvature = _fit_peak(patch)
        assert np.array_equal(got_offset, want_offset) and got_value == want_value and got_curvature == want_curvature


def test_distinct_peak_level_is_its_definition():
    rng = np.random.default_rng(11)
    for _ in range(500):
        arguments = (rng.uniform(-0.2, 1.0), rng.uniform(1.0, 500.0), rng.uniform(1.0, 500.0), rng.uniform(0.0, 20.0),
                     rng.uniform(0.0, 20.0), int(rng.integers(9, 200)), rng.uniform(0.0, 5.0))
        assert distinct_peak_level(*arguments) == _distinct_peak_level(*arguments)


def _second_peak(surface, best, exclusion_px):
    """Highest 3 x 3 local maximum away from ``best`` by OpenCV (dilate, compare, masked minMaxLoc)."""
    import cv2
    local = cv2.compare(surface, cv2.dilate(surface, np.ones((3, 3), np.uint8)), cv2.CMP_GE)
    column, row = best
    local[max(row - exclusion_px, 0): row + exclusion_px + 1, max(column - exclusion_px, 0): column + exclusion_px + 1] = 0
    _, highest, _, where = cv2.minMaxLoc(surface, local)
    return float(highest) if where[0] >= 0 else -1.0


def _surfaces(seed, count=60):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        rows, columns = rng.integers(3, 25, 2)
        smooth = rng.standard_normal((rows + 4, columns + 4)).cumsum(axis=0).cumsum(axis=1)
        surface = smooth[2:-2, 2:-2] / np.abs(smooth).max()
        yield np.round(surface, int(rng.integers(1, 4))).astype(np.float32)     # rounded: ties and plateaus too


def test_peak_and_second_are_opencvs():
    import cv2
    for surface in _surfaces(21):
        for exclusion in (0, 1, 3):
            best, column, row, second = compiled.peak_and_second(surface, exclusion)
            _, want_best, _, want_where = cv2.minMaxLoc(surface)
            assert (best, (column, row)) == (want_best, want_where)
            assert second == _second_peak(surface, want_where, exclusion)


def test_lobes_are_opencvs_connected_components():
    import cv2

    from dimes_velocity.matching import lobes_above
    for surface in _surfaces(22):
        for level in (0.0, 0.3, -0.2, float(surface.max()), 0.1 + 1e-9):
            above = np.ascontiguousarray(surface >= level, dtype=np.uint8)
            want = int(cv2.connectedComponents(above, connectivity=8)[0]) - 1
            assert lobes_above(surface, level) == want


def test_variance_is_numpys():
    rng = np.random.default_rng(23)
    image = (rng.standard_normal((80, 80)) * 10.0 ** rng.uniform(-3, 5, (80, 80))).astype(np.float32)
    for _ in range(200):
        row, column, side = int(rng.integers(0, 50)), int(rng.integers(0, 50)), int(rng.integers(3, 30))
        window = image[row: row + side, column: column + side]
        mean = np.add.reduce(window, axis=None, dtype=np.float64, keepdims=True) / window.size
        deviations = np.square(np.subtract(window, mean))
        assert compiled.variance(window) == float(np.add.reduce(deviations, axis=None, dtype=np.float64) / window.size)
        assert compiled.variance(window) == float(window.astype(np.float64).var())


def test_grid_maxima_is_the_per_cell_argmax_of_the_allowed_interest():
    """``compiled.grid_maxima`` against its numpy definition, ties, empty cells, refused cells and NaN included."""
    rng = np.random.default_rng(12)
    for trial in range(100):
        rows, columns = rng.integers(1, 60, 2)
        interest = rng.integers(0, 5, (rows, columns)).astype(np.float32)          # many equal maxima
        if trial % 5 == 0:
            interest[rng.integers(0, rows), rng.integers(0, columns)] = np.nan
        candidates = rng.random((rows, columns)) < (0.05 if trial % 3 == 0 else 0.7)
        cells = int(rng.integers(1, 6))
        row_edges = np.linspace(0, rows, cells + 1).astype(int)
        column_edges = np.linspace(0, columns, cells + 1).astype(int)
        scored = np.where(candidates, interest, -1.0)
        expected = []
        for upper, lower in zip(row_edges[:-1], row_edges[1:]):
            for first, last in zip(column_edges[:-1], column_edges[1:]):
                cell = scored[upper:lower, first:last]
                if cell.size == 0:
                    continue
                row, column = divmod(int(cell.argmax()), cell.shape[1])
                if not cell[row, column] < 0:
                    expected.append((float(cell[row, column]), first + column, upper + row))
        scores, found_columns, found_rows = compiled.grid_maxima(interest, candidates, row_edges, column_edges)
        got = list(zip(scores.tolist(), found_columns.tolist(), found_rows.tolist()))
        assert len(got) == len(expected)
        for (score, column, row), (score_e, column_e, row_e) in zip(got, expected):
            assert (column, row) == (column_e, row_e)
            assert score == score_e or (np.isnan(score) and np.isnan(score_e))


def test_square_erosion_is_opencvs_with_a_zero_border():
    """The estimator's erosion (two run-counting passes) against ``cv2.erode`` by the square, outside = 0."""
    import cv2

    from dimes_velocity.estimator import _erode

    rng = np.random.default_rng(13)
    for trial in range(200):
        rows, columns = (int(value) for value in rng.integers(1, 80, 2))
        mask = rng.random((rows, columns)) < rng.uniform(0.6, 1.0)
        if trial % 4 == 0:
            mask[:] = True                                     # only the border erodes
        half = int(rng.integers(0, 45))
        kernel = np.ones((2 * half + 1, 2 * half + 1), np.uint8)
        expected = cv2.erode(mask.view(np.uint8), kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0).view(bool)
        eroded = _erode(mask, half)
        assert eroded.dtype == bool and np.array_equal(eroded, expected)
