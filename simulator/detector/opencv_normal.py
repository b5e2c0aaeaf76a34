"""OpenCV's standard normal float32 generator (``cv2.setRNGSeed`` then ``cv2.randn``), reproduced bit for bit in numba.

The read-out's normal deviates (:func:`simulator.detector.readout.standard_normal_f32`, one per binned
pixel) are OpenCV's; this module gives the same samples from compiled code, ~20 % faster than
``cv2.randn`` (:func:`_fill_kernel`: one loop over the state's draws in which a wedge's decision moves the
write position instead of a branch; no per-block scaling pass). Drawing them inside the read-out's own
pass instead was measured slower, as it keeps that pass from being vectorised.

OpenCV's generator (``modules/core/src/rand.cpp``, checked on the installed build by
:func:`generator_matches_opencv`):

* The state is a 64-bit multiply-with-carry, ``state <- low32(state) * 4164903690 + (state >> 32)``
  (unsigned 64-bit arithmetic); ``cv2.setRNGSeed(seed)`` sets the state to ``seed`` (thread-local, the
  same generator ``cv2.randn`` then uses). ``randn`` fills the array in blocks in row-major order, the state
  passing on from block to block, so the samples are one sequence whatever the shape.
* Each sample is Marsaglia and Tsang's ziggurat (128 strips) in float32: ``hz`` = the state's low 32 bits as
  a signed integer, read *before* the state advances; strip ``i = hz & 127``; ``x = float32(hz) * w[i]``,
  accepted if ``|hz| < k[i]`` (as unsigned). Otherwise, in the base strip (``i = 0``), the tail beyond
  ``r = 3.44262``: two uniforms ``u = float32(low32(state)) * 2^-32`` (each one state step),
  ``x = float32(-logf(u1 + FLT_MIN) * 0.2904764)`` (``0.2904764 ~ 1 / r``, the product in double),
  ``y = -logf(u2 + FLT_MIN)``, repeated until ``2 y >= x^2``, then ``+-(r + x)`` with the sign of ``hz``;
  in the wedge of strip ``i > 0``, one uniform ``u`` and acceptance if
  ``f[i] + u (f[i-1] - f[i]) < exp(-x^2 / 2)`` (left side float32, right side the double ``exp``), else a
  new ``hz``. ``logf`` is the C library's float logarithm, ``exp`` its double exponential (glibc here).
* The tables ``k`` (uint32), ``w``, ``f`` (float32) are built in double from ``r`` and the strip area
  ``v = 9.91256303526217e-3`` (:func:`ziggurat_tables`).
* ``randn(samples, 0, 1)`` then scales each sample as ``x * 1 + 0`` in float32, which leaves it unchanged
  (no sample is ``-0``).

Another OpenCV build or C library could differ (a changed generator, another ``logf``); the callers check
once per process and image size (:func:`generator_matches_opencv`) and use ``cv2.randn`` where it differs.
"""
from __future__ import annotations

import math
from functools import lru_cache

import cv2
import numpy as np
from numba import njit

MWC_MULTIPLIER = 4164903690          # OpenCV's CV_RNG_COEFF
TAIL_START = 3.442620                # r: where the base strip's tail starts (float32 in OpenCV)
#: cv2.randn's mean and standard deviation as the arrays its stubs declare (the same samples as the scalars 0, 1)
_RANDN_MEAN, _RANDN_STDDEV = np.zeros(1), np.ones(1)
_PROBE_SEED = 1_927_364_101          # the seed of the one-off comparison with cv2.randn


def ziggurat_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV's 128-strip ziggurat tables, built in double with the C library's ``exp``, ``log`` and ``sqrt``.

    Returns
    -------
    (k, w, f) : ndarray uint32, ndarray float32, ndarray float32, each shape (128,)
        Strip ``i`` (1 .. 127, ``x_i`` increasing with ``i`` up to ``x_127 = r``) spans ``|x| <= x_i``:
        ``w[i] = x_i / 2^31`` (a sample is ``hz * w[i]``), ``f[i] = exp(-x_i^2 / 2)`` (``f[0] = 1``), and
        ``k[i] = 2^31 x_(i-1) / x_i`` bounds the draws accepted at once, ``|hz| < k[i]`` (``k[1] = 0``: every
        draw of strip 1 goes to its wedge). Strip 0 is the base: ``w[0]`` and ``k[0]`` from its equivalent
        width ``v / f(r)``.
    """
    scale = 2147483648.0                      # 2^31
    edge = 3.442619855899                     # x_127: the outermost strip's edge, the tail start r in double
    previous_edge = edge
    strip_area = 9.91256303526217e-3
    k = np.zeros(128, dtype=np.uint32)
    w = np.zeros(128, dtype=np.float32)
    f = np.zeros(128, dtype=np.float32)
    base = strip_area / math.exp(-0.5 * edge * edge)      # the base strip's equivalent width
    k[0] = int((edge / base) * scale)
    k[1] = 0
    w[0] = np.float32(base / scale)
    w[127] = np.float32(edge / scale)
    f[0] = np.float32(1.0)
    f[127] = np.float32(math.exp(-0.5 * edge * edge))
    for strip in range(126, 0, -1):
        edge = math.sqrt(-2.0 * math.log(strip_area / edge + math.exp(-0.5 * edge * edge)))
        k[strip + 1] = int((edge / previous_edge) * scale)
        previous_edge = edge
        f[strip] = np.float32(math.exp(-0.5 * edge * edge))
        w[strip] = np.float32(edge / scale)
    return k, w, f


ZIGGURAT_K, ZIGGURAT_W, ZIGGURAT_F = ziggurat_tables()


@njit(cache=True, nogil=True, boundscheck=False)
def next_state(state):
    """One step of OpenCV's multiply-with-carry.

    Parameters
    ----------
    state : uint64
        Generator state.

    Returns
    -------
    uint64
        ``low32(state) * 4164903690 + (state >> 32)``.
    """
    return (state & np.uint64(0xFFFFFFFF)) * np.uint64(MWC_MULTIPLIER) + (state >> np.uint64(32))


@njit(cache=True, nogil=True, boundscheck=False)
def _uniform(state):
    """The state's low 32 bits as a float32 in [0, 1): ``float32(low32) * 2^-32``."""
    return np.float32(np.uint32(state & np.uint64(0xFFFFFFFF))) * np.float32(2.3283064365386962890625e-10)


@njit(cache=True, nogil=True, boundscheck=False)
def _fill_kernel(seed, samples, k, w, f):
    """Fill the flat float32 ``samples`` in order with OpenCV's ziggurat (module doc) from the state ``seed``.

    One iteration per ``hz`` draw: its candidate sample is written at the next free place, which moves on
    unless a wedge rejected it (a rejection and an acceptance consume the state alike, so the wedge's ``exp``
    delays only that place, not the state's chain or a mispredicted branch).

    Parameters
    ----------
    seed : int
        OpenCV seed (the initial state).
    samples : ndarray, float32, shape (n,)
        Written: the samples.
    k, w, f : ndarray uint32, float32, float32, shape (128,)
        :func:`ziggurat_tables`.

    Returns
    -------
    uint64
        The state after the last sample.
    """
    tail_start = np.float32(TAIL_START)
    smallest_normal = np.float32(1.1754943508222875e-38)        # FLT_MIN
    state = np.uint64(seed)
    count = samples.size
    index = 0
    while index < count:
        bits = np.uint32(state & np.uint64(0xFFFFFFFF))
        hz = np.int32(bits)
        state = next_state(state)
        strip = hz & 127
        x = np.float32(hz) * w[strip]
        magnitude = bits if hz >= 0 else np.uint32(-np.int64(hz))
        keep = 1
        if magnitude >= k[strip]:
            if strip == 0:                   # the tail beyond r
                while True:
                    first = _uniform(state)
                    state = next_state(state)
                    second = _uniform(state)
                    state = next_state(state)
                    x = np.float32(np.float64(-math.log(first + smallest_normal)) * 0.2904764)
                    y = -math.log(second + smallest_normal)
                    if not y + y < x * x:
                        break
                x = tail_start + x if hz > 0 else -tail_start - x
            else:                            # the wedge of strip i > 0
                y = _uniform(state)
                state = next_state(state)
                x64 = np.float64(x)
                keep = int(f[strip] + y * (f[strip - 1] - f[strip]) < math.exp(-0.5 * x64 * x64))
        samples[index] = x
        index += keep
    return state


def seeded_standard_normal_f32(seed: int, shape: tuple[int, ...], out: np.ndarray | None = None,
                               generator: str = "checked") -> np.ndarray:
    """The samples of ``cv2.setRNGSeed(seed); cv2.randn(out, 0.0, 1.0)`` on a float32 array.

    Parameters
    ----------
    seed : int
        OpenCV seed, 1 .. 2^31 - 1.
    shape : tuple of int
        Shape of the samples (filled in row-major order; 1-D or 2-D: OpenCV reads a third axis as channels).
    out : ndarray, float32, shape ``shape``, optional
        Where to write them (else a new array).
    generator : {"checked", "numba", "opencv"}
        ``"numba"``: the reproduction (:func:`_fill_kernel`; ``out`` C-contiguous); ``"opencv"``: OpenCV's own
        call; ``"checked"``: the reproduction where :func:`generator_matches_opencv` holds for this shape and
        ``out`` is C-contiguous, else OpenCV's.

    Returns
    -------
    ndarray, float32, shape ``shape``
        Samples of N(0, 1).

    Raises
    ------
    ValueError
        ``"numba"`` with an ``out`` that is not a C-contiguous float32 array, or another generator name.
    """
    samples = np.empty(shape, dtype=np.float32) if out is None else out
    if generator not in ("checked", "numba", "opencv"):
        raise ValueError(f"generator {generator!r}: expected 'checked', 'numba' or 'opencv'")
    fits = samples.dtype == np.float32 and samples.ndim <= 2 and samples.flags.c_contiguous
    if generator == "numba" and not fits:
        raise ValueError("out must be a C-contiguous float32 array of 1 or 2 dimensions")
    if generator == "numba" or (generator == "checked" and fits and generator_matches_opencv(samples.shape)):
        _fill_kernel(seed, samples.reshape(-1), ZIGGURAT_K, ZIGGURAT_W, ZIGGURAT_F)
    else:
        cv2.setRNGSeed(seed)
        cv2.randn(samples, _RANDN_MEAN, _RANDN_STDDEV)
    return samples


@lru_cache(maxsize=64)
def generator_matches_opencv(shape: tuple[int, ...]) -> bool:
    """Whether the reproduction gives ``cv2.randn``'s bits for this shape (checked once, on one seed).

    Parameters
    ----------
    shape : tuple of int
        Shape of the samples, 1-D or 2-D.

    Returns
    -------
    bool
        True when all samples of the probe seed are bit-identical to OpenCV's (a 256 x 1024 image takes
        ~150 tail and ~4000 wedge samples).
    """
    ours = seeded_standard_normal_f32(_PROBE_SEED, shape, generator="numba")
    theirs = seeded_standard_normal_f32(_PROBE_SEED, shape, generator="opencv")
    return bool(np.array_equal(ours.view(np.uint32), theirs.view(np.uint32)))
