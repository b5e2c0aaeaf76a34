"""The numba reproduction of OpenCV's normal generator against ``cv2.setRNGSeed`` + ``cv2.randn`` itself.

Bit equality (as uint32) over seeds and sizes, with the tail and wedge paths shown to be exercised; the
ziggurat tables against the ziggurat's defining property (equal strip areas); and the read-out, default and
exact presets, identical whichever generator draws its deviates.
"""
import math

import cv2
import numpy as np
import pytest

from simulator.detector import opencv_normal, readout

TAIL_START = 3.44262   # r: only the base strip's tail gives |x| beyond it


def _opencv_samples(seed, shape):
    samples = np.empty(shape, dtype=np.float32)
    cv2.setRNGSeed(seed)
    cv2.randn(samples, 0.0, 1.0)
    return samples


def _seeds(count):
    """The extreme seeds and random ones from the range the read-out draws (1 .. 2^31 - 2)."""
    rng = np.random.default_rng(20261127)
    return [1, 2, 2**31 - 2] + [int(seed) for seed in rng.integers(1, 2**31 - 1, count)]


def test_samples_are_cv2_randns_bit_for_bit_over_seeds_and_sizes():
    """24 read-out images (256 x 1024) and odd sizes (OpenCV fills in blocks; the state runs on across them)."""
    cases = [(seed, (256, 1024)) for seed in _seeds(21)]
    cases += [(seed, shape) for seed, shape in zip(_seeds(7), [(1, 1), (1, 7), (3, 1025), (1025, 3), (1023,), (4097,),
                                                                (512, 1024), (1024, 1024), (7, 333), (2, 2)])]
    tails = 0
    for seed, shape in cases:
        ours = opencv_normal.seeded_standard_normal_f32(seed, shape, generator="numba")
        theirs = _opencv_samples(seed, shape)
        assert ours.shape == theirs.shape and ours.dtype == np.float32
        differ = ours.view(np.uint32) != theirs.view(np.uint32)
        assert not differ.any(), (seed, shape, np.flatnonzero(differ)[:5])
        tails += int((np.abs(theirs) > TAIL_START).sum())
    assert tails > 2000          # ~150 tail samples per image: the logf path is compared


def test_the_comparison_sees_the_wedges():
    """With the wedge heights ``f`` off by 0.1 % the samples differ: wedge decisions are among those compared."""
    seed, samples = 77, np.empty(262144, dtype=np.float32)
    theirs = _opencv_samples(seed, samples.shape)
    opencv_normal._fill_kernel(seed, samples, opencv_normal.ZIGGURAT_K, opencv_normal.ZIGGURAT_W,
                               opencv_normal.ZIGGURAT_F)
    assert np.array_equal(samples.view(np.uint32), theirs.view(np.uint32))
    opencv_normal._fill_kernel(seed, samples, opencv_normal.ZIGGURAT_K, opencv_normal.ZIGGURAT_W,
                               (opencv_normal.ZIGGURAT_F * np.float32(0.999)).astype(np.float32))
    assert not np.array_equal(samples.view(np.uint32), theirs.view(np.uint32))


def test_tables_are_a_ziggurat_of_equal_strips():
    """Strip i (1..127) spans x_i = w_i 2^31 and the density values f; each rectangle x_i (f_(i-1) - f_i) has the
    area v, as has the base strip (r f(r) + the normal tail beyond r, unnormalised); k_i / 2^31 = x_(i-1) / x_i."""
    k, w, f = opencv_normal.ZIGGURAT_K, opencv_normal.ZIGGURAT_W, opencv_normal.ZIGGURAT_F
    assert (k.dtype, w.dtype, f.dtype) == (np.uint32, np.float32, np.float32)
    edges = w.astype(np.float64) * 2.0**31
    area = 9.91256303526217e-3
    assert edges[127] == pytest.approx(TAIL_START, rel=1e-6)
    np.testing.assert_allclose(f[1:], np.exp(-0.5 * edges[1:] ** 2), rtol=2e-6)
    np.testing.assert_allclose(edges[1:] * (f[:-1].astype(np.float64) - f[1:]), area, rtol=1e-4)
    tail = math.sqrt(math.pi / 2) * math.erfc(TAIL_START / math.sqrt(2))
    assert TAIL_START * math.exp(-0.5 * TAIL_START**2) + tail == pytest.approx(area, rel=1e-5)
    assert k[1] == 0
    np.testing.assert_allclose(k[2:] / 2.0**31, edges[1:-1] / edges[2:], rtol=2e-7)


def test_the_generator_is_checked_and_used_for_the_read_out_size():
    assert opencv_normal.generator_matches_opencv((256, 1024))
    rng = np.random.default_rng(3)
    seed = int(np.random.default_rng(3).integers(1, 2**31 - 1))
    drawn = readout.standard_normal_f32(rng, (256, 1024))
    assert np.array_equal(drawn.view(np.uint32), _opencv_samples(seed, (256, 1024)).view(np.uint32))


def _realistic_mean_e(electronics):
    """Binned means across the whole range: a sky-to-terrain gradient with texture, dark shadows (exact Poisson
    below 1000 e-) and saturated spots above the full well."""
    rng = np.random.default_rng(31)
    rows, cols = np.mgrid[0:256, 0:1024]
    terrain = 0.55 * electronics.binned_full_well_e * (0.3 + 0.7 * rows / 255.0) * (1.0 + 0.2 * np.sin(cols / 37.0))
    mean = terrain * rng.lognormal(0.0, 0.25, terrain.shape)
    mean[40:60, 100:400] = rng.uniform(0.0, 1200.0, (20, 300))             # shadow
    mean[200:210, 900:950] = 1.3 * electronics.binned_full_well_e         # saturated
    return mean.astype(np.float32)


@pytest.mark.parametrize("exact_poisson", [False, True])
def test_read_out_is_the_same_with_opencvs_generator(mer_a, monkeypatch, exact_poisson):
    """The read-out (default fused pass and exact presets) gives the same DN and expected DN when its deviates come
    from cv2.randn (the guard's fallback)."""
    electronics = mer_a.electronics
    mean = _realistic_mean_e(electronics)
    assert (mean < readout.GAUSSIAN_MIN_MEAN_E).sum() > 1000
    ours = readout.read_out_dn(np.random.default_rng(41), mean, electronics, exact_poisson=exact_poisson)
    monkeypatch.setattr(opencv_normal, "generator_matches_opencv", lambda shape: False)
    theirs = readout.read_out_dn(np.random.default_rng(41), mean, electronics, exact_poisson=exact_poisson)
    assert np.array_equal(ours[0], theirs[0])
    assert np.array_equal(ours[1].view(np.uint32), theirs[1].view(np.uint32))
    other = readout.read_out_dn(np.random.default_rng(42), mean, electronics, exact_poisson=exact_poisson)
    assert not np.array_equal(ours[0], other[0])


def test_out_must_be_contiguous_float32():
    with pytest.raises(ValueError, match="C-contiguous float32"):
        opencv_normal.seeded_standard_normal_f32(5, (4, 4), out=np.empty((4, 8), dtype=np.float32)[:, ::2], generator="numba")
