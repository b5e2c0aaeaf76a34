"""The exact presets' shot noise: Poisson by inversion of the default preset's normal deviates.

Against scipy.stats (the Poisson quantile, CDF and pmf) and closed forms: the draw is exact Poisson in
distribution (moments, chi-square at small and large means), its read noise is an independent
Gaussian, and on the same seed it equals the default preset's Gaussian draw up to the Poisson skewness.
"""
import numpy as np
import pytest
from scipy import special, stats

from simulator.detector import coupled_poisson, readout
from simulator.detector.coupled_poisson import poisson_quantile


def test_inversion_is_scipys_poisson_quantile_from_dim_to_huge_means():
    """|u| <= 4, where scipy's CDF is accurate at every mean: each count k is the Poisson quantile of Phi(u) by its
    definition, the smallest k with F(k) >= Phi(u), i.e. F(k - 1) < Phi(u) <= F(k) with scipy's F (what
    ``stats.poisson.ppf`` returns, checked in two CDF calls instead of its search: 0.05 s instead of 10 s)."""
    rng = np.random.default_rng(20)
    deviate = rng.uniform(-4.0, 4.0, 60_000)
    mean = np.exp(rng.uniform(np.log(1e-3), np.log(1e10), deviate.size))
    count = poisson_quantile(deviate, mean)
    level = stats.norm.cdf(deviate)
    assert np.array_equal(count, np.floor(count)) and (count >= 0).all()
    below, at = stats.poisson.cdf(count - 1, mean), stats.poisson.cdf(count, mean)
    wrong = ~((below < level) & (level <= at))
    assert not wrong.any(), np.c_[deviate, mean, count][wrong][:10]


@pytest.mark.parametrize("mean", [2.0e3, 7.0e4, 1.0e6, 1.0e7])
def test_tail_counts_bracket_the_tail_probability_by_a_direct_pmf_sum(mean):
    """4 <= |u| <= 8, where scipy's upper tail is inaccurate at large means (4e-2 relative at 1e7): the
    tail beyond the count, summed term by term from log pmf, must straddle the normal tail:
    P(X > k) <= Phi(-u) < P(X > k - 1) above, P(X <= k - 1) < Phi(u) <= P(X <= k) below."""
    deviate = np.concatenate([np.linspace(4.0, 8.0, 9), -np.linspace(4.0, 8.0, 9)])
    counts = poisson_quantile(deviate, np.full(deviate.size, mean))
    width = np.floor(60 * np.sqrt(mean)) + 200
    for u, count in zip(deviate, counts):
        if u > 0:
            terms = np.arange(count, count + width)                 # P(X > count - 1), first term k = count
            pmf = np.exp(terms * np.log(mean) - mean - special.gammaln(terms + 1))
            above, at = pmf.sum(), pmf[1:].sum()                   # P(X > k - 1), P(X > k)
            assert at <= special.ndtr(-u) * (1 + 1e-9) and special.ndtr(-u) * (1 - 1e-9) < above
        else:
            terms = np.arange(max(count - width, 0.0), count + 1)   # up to P(X <= count)
            pmf = np.exp(terms * np.log(mean) - mean - special.gammaln(terms + 1))
            at, below = pmf.sum(), pmf[:-1].sum()
            assert below < special.ndtr(u) * (1 + 1e-9) and special.ndtr(u) * (1 - 1e-9) <= at


@pytest.mark.parametrize("mean", [0.3, 5.0, 29.5, 99.5, 150.0, 640.0, 1000.5, 2.5e5, 3.0e7, 4.0e9])
def test_deviates_next_to_a_cdf_step_fall_on_its_two_sides(mean):
    """u = Phi^-1(F(k; m)) -/+ 1e-9 must give k and k + 1: the pixels the expansion's margin sends to
    the exact CDF (the count is the smallest k with F(k) >= Phi(u))."""
    spread = 3.0 * np.sqrt(mean)
    counts = np.unique(np.floor(np.linspace(max(mean - spread, 0.0), mean + spread, 41)))
    step = stats.norm.ppf(stats.poisson.cdf(counts, mean))
    means = np.full(counts.size, mean)
    assert np.array_equal(poisson_quantile(step - 1e-9, means), counts)
    assert np.array_equal(poisson_quantile(step + 1e-9, means), counts + 1)


def test_far_tails_and_mixed_paths_meet_the_quantile_definition():
    """Dim pixels, |u| beyond the expansion's range and bright pixels in one array: each count k has
    F(k - 1) < Phi(u) <= F(k) (checked on the tail where Phi(u) is accurate)."""
    deviate = np.array([-8.5, -6.0, 0.0, 6.0, 8.5, -9.0, 9.0, 0.7, -0.7, 3.0, 8.9, -8.9, 5.5, -5.5, 4.9, 2.0])
    mean = np.array([2.0, 2.0, 2.0, 2.0, 2.0, 5.0e3, 5.0e3, 5.0e3, 999.0, 0.0, 1.0e6, 1.0e6, 300.0, 300.0, 120.0,
                     60.0])
    counts = poisson_quantile(deviate, mean)
    lower = deviate <= 0
    assert np.all(np.where(lower, stats.poisson.cdf(counts, mean) >= stats.norm.cdf(deviate),
                           stats.poisson.sf(counts, mean) <= stats.norm.sf(deviate)))
    below = counts - 1.0
    assert np.all((counts == 0) | np.where(lower, stats.poisson.cdf(below, mean) < stats.norm.cdf(deviate),
                                           stats.poisson.sf(below, mean) > stats.norm.sf(deviate)))
    assert counts[mean == 0.0].tolist() == [0.0]


def test_expansion_error_is_far_inside_the_boundary_margin():
    """The Cornish-Fisher quantile against y solving Q(y + 1, m) = Phi(u) by bisection: bright means with
    |u| <= 8 and dim means with |u| <= 5 (the error falls as 1 / m^2): below 1/40 of the margin."""
    bright = (coupled_poisson.EXPANSION_MIN_MEAN_E, 3.0e3, 1.0e4, 1.0e5)
    dim = (coupled_poisson.DIM_MIN_MEAN_E, 180.0, 400.0, 999.0)
    cases = [(value, coupled_poisson.EXPANSION_MAX_DEVIATE) for value in bright] \
        + [(value, coupled_poisson.DIM_MAX_DEVIATE) for value in dim]
    for mean_value, largest in cases:
        deviate = np.linspace(-largest, largest, 161)
        mean = np.full(deviate.size, mean_value)
        low, high = mean + np.sqrt(mean) * deviate - 50.0, mean + np.sqrt(mean) * deviate + 50.0
        low = np.maximum(low, -0.999)
        upper = deviate > 0
        for _ in range(80):                 # Q(a, m) rises with a; compare on the accurate tail
            middle = 0.5 * (low + high)
            rising = np.where(upper, special.gammainc(middle + 1.0, mean) > special.ndtr(-deviate),
                              special.gammaincc(middle + 1.0, mean) < special.ndtr(deviate))
            low, high = np.where(rising, middle, low), np.where(rising, high, middle)
        error = np.abs(coupled_poisson._continuous_quantile(deviate, mean) - 0.5 * (low + high))
        margin = max(coupled_poisson.BOUNDARY_MARGIN, coupled_poisson.DIM_MARGIN_E2 / mean_value**2)
        assert error.max() < margin / 40, (mean_value, error.max())


@pytest.mark.parametrize("mean", [0.7, 4.0, 12.5, 29.0, 400.0, 999.9, 1000.1, 3.3e4, 2.5e5])
def test_exact_preset_shot_noise_is_poisson_mean_variance_and_chi_square(mean):
    count = 200_000
    draws = readout.noisy_charge_e(np.random.default_rng(int(mean * 10)), np.full(count, mean), 0.0,
                                   read_noise=False, exact_poisson=True)
    assert np.all(draws == np.round(draws)) and draws.min() >= 0
    assert abs(draws.mean() - mean) < 5 * np.sqrt(mean / count)
    assert abs(draws.var() - mean) < 5 * np.sqrt((2 * mean**2 + mean) / count)
    assert _chi_square_p_value(draws, mean) > 1e-4


def _chi_square_p_value(draws, mean, min_expected=20.0):
    """Pearson's chi-square of integer draws against Poisson(mean), cells merged until each expects
    >= ``min_expected`` (the two tails into the end cells)."""
    low, high = stats.poisson.ppf([1e-6, 1 - 1e-6], mean)
    edges = [low]
    for value in np.arange(low + 1, high + 1):
        cell = stats.poisson.cdf(value - 1, mean) - stats.poisson.cdf(edges[-1] - 1, mean)
        if cell * draws.size >= min_expected:
            edges.append(value)
    cells = np.diff(stats.poisson.cdf(np.array(edges[1:]) - 1, mean), prepend=0.0)
    cells = np.append(cells, stats.poisson.sf(edges[-1] - 1, mean))
    observed = np.bincount(np.searchsorted(edges[1:], draws, side="right"), minlength=cells.size)
    expected = cells / cells.sum() * draws.size
    return stats.chisquare(observed, expected, ddof=0).pvalue


def test_read_noise_is_gaussian_and_independent_of_the_count():
    """Read noise 0.05 e-: the count is the charge rounded, the rest the read noise, which must be
    N(0, 0.05^2) (KS) and uncorrelated with the count (the rotation's two deviates are independent)."""
    mean, sigma, count = 2.5e5, 0.05, 200_000
    charge = readout.noisy_charge_e(np.random.default_rng(8), np.full(count, mean), sigma, exact_poisson=True)
    shots = np.round(charge)
    read = (charge - shots) / sigma
    assert stats.kstest(read, "norm").pvalue > 1e-3
    assert abs(np.corrcoef(read, shots)[0, 1]) < 5 / np.sqrt(count)
    assert _chi_square_p_value(shots, mean) > 1e-4


def test_exact_draw_follows_the_default_draw_on_the_same_seed():
    """Same seed, bright pixels: exact - default = ceil(y) - y + (u^2 - 1) / 6 - 1/2 + O(m^-1/2), a
    uniform rounding residual and the Poisson skewness: mean 0, RMS sqrt(1/12 + 2/36) = 0.373 e-
    (against a noise of sqrt(m + s^2) ~ 500 e-); with an independent seed the difference is ~700 e-."""
    mean = np.random.default_rng(3).uniform(1.5e5, 3.0e5, 262_144)
    exact = readout.noisy_charge_e(np.random.default_rng(5), mean, 30.0, exact_poisson=True)
    default = readout.noisy_charge_e(np.random.default_rng(5), mean, 30.0)
    difference = exact - default
    assert abs(difference.mean()) < 5 * 0.373 / np.sqrt(mean.size)
    assert np.sqrt(np.mean(difference**2)) == pytest.approx(np.sqrt(1 / 12 + 2 / 36), rel=0.02)
    independent = readout.noisy_charge_e(np.random.default_rng(6), mean, 30.0, exact_poisson=True)
    assert np.sqrt(np.mean((independent - default) ** 2)) > 600.0


def test_dim_pixels_read_noise_is_the_default_deviate_and_huge_means_pass_through():
    """m = 0: b = 1, the read noise is s z (the default's own draw: same as its Gaussian at m = 0 would be);
    means above the Poisson limit (and +inf) are returned without shot noise; NaN is refused."""
    mean = np.zeros(1000)
    exact = readout.noisy_charge_e(np.random.default_rng(4), mean, 30.0, exact_poisson=True)
    z = readout.standard_normal_f32(np.random.default_rng(4), mean.shape).astype(np.float64)
    assert np.allclose(exact, 30.0 * z, rtol=0, atol=1e-9)
    huge = np.array([2e18, np.inf, 5e19])
    assert np.array_equal(poisson_quantile(np.zeros(3), huge), huge)
    with pytest.raises(ValueError, match="NaN"):
        poisson_quantile(np.zeros(2), np.array([1.0, np.nan]))
    assert coupled_poisson.MAX_POISSON_MEAN_E == readout.MAX_POISSON_MEAN_E
