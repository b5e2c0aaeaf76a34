"""Off-nominal camera effects against their own physics: dust shadows, hot pixels, particle hits, blooming."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from flight_interface.cahvor import cahvor_from_intrinsics
from flight_interface.camera import load_camera
from simulator.detector import blooming
from simulator.detector.camera_chain import CameraEffects, render_image
from simulator.off_nominal import OffNominalArtefacts, dust, hot_pixels, particle_hits

ROOT = Path(__file__).resolve().parents[3]
CAMERA = load_camera(ROOT / "sitedata" / "cameras" / "mer_a.toml")
FOCAL_M = 0.01467
FOCAL_PX = FOCAL_M / 12e-6
PUPIL_RADIUS_M = 0.5 * FOCAL_M / 12.0
PINHOLE = replace(CAMERA, model=cahvor_from_intrinsics(FOCAL_M, 12e-6, (511.5, 511.5)))
NOISE_FREE = CameraEffects(shot_noise=False, read_noise=False)


# ---------------------------------------------------------------- dust

def test_disc_overlap_area_matches_monte_carlo():
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.0, 1.0, (400_000, 2))            # square of area 4 around the unit disc
    in_unit = np.hypot(points[:, 0], points[:, 1]) <= 1.0
    for radius, separation in ((0.3, 0.0), (0.3, 0.85), (0.3, 1.2), (0.7, 0.9), (1.5, 0.4), (0.5, 1.6)):
        in_other = np.hypot(points[:, 0] - separation, points[:, 1]) <= radius
        estimate = 4.0 * np.mean(in_unit & in_other)
        sigma = 4.0 * np.sqrt(np.mean(in_unit & in_other) / points.shape[0]) + 1e-9
        assert float(dust.overlap_area(1.0, radius, separation)) == pytest.approx(estimate, abs=5 * sigma + 1e-4)


@pytest.mark.parametrize("diameter_m", [200e-6, 1.6e-3])
@pytest.mark.parametrize("interpolated", [False, True])
def test_single_particle_shadow_follows_the_pupil_geometry(diameter_m, interpolated):
    distance = 8e-3
    a = 0.5 * diameter_m
    position = np.array([1.0e-3, -0.6e-3])
    particles = dust.DustParticles(position[None, :], np.array([diameter_m]))
    make = dust.transmission_map if interpolated else dust.transmission_map_exact
    transmission = make(PINHOLE, particles, distance).astype(np.float64)
    # the node-grid map blends over one node step (4 px) at the band edges
    edge = 1.0 + (2.0 * dust.NODE_STEP_PX if interpolated else 0.0)
    assert dust.entrance_pupil_radius_m(PINHOLE) == pytest.approx(PUPIL_RADIUS_M, rel=1e-9)

    centre = np.array([511.5, 511.5]) + FOCAL_PX * position / distance       # chief ray through the particle
    rows, cols = np.mgrid[0:1024, 0:1024]
    radius_px = np.hypot(cols - centre[0], rows - centre[1])
    scale = FOCAL_PX / distance                                                # px per m on the front element
    outer, inner = (PUPIL_RADIUS_M + a) * scale, abs(PUPIL_RADIUS_M - a) * scale
    assert np.all(transmission[radius_px > outer + edge] == 1.0)
    core = transmission[radius_px < inner - edge]
    expected_depth = min((a / PUPIL_RADIUS_M) ** 2, 1.0)                      # particle area / pupil area
    assert core.size > 100 and np.allclose(1.0 - core, expected_depth, atol=2e-6)
    ring = (radius_px > inner + edge) & (radius_px < outer - edge)
    assert np.all((transmission[ring] > 1.0 - expected_depth) & (transmission[ring] < 1.0))
    # the blocked area integrated over the image is the particle area magnified by f_px / d
    blocked_px2 = float(np.sum(1.0 - transmission))
    assert blocked_px2 == pytest.approx(np.pi * a**2 * scale**2, rel=2e-3)


def test_dust_population_statistics_and_transmission_of_many_particles():
    distance, scale_m, max_m = 8e-3, 150e-6, 1e-3
    aperture = dust.clear_aperture_radius_m(CAMERA, distance)
    counts, diameters, radii2 = [], [], []
    for seed in range(300):
        particles = dust.draw_particles(CAMERA, np.random.default_rng(seed), 12, scale_m, max_m, distance)
        counts.append(particles.diameters_m.size)
        diameters.extend(particles.diameters_m)
        radii2.extend(np.sum(particles.positions_m**2, axis=1))
    assert np.mean(counts) == pytest.approx(12.0, abs=4 * np.sqrt(12.0 / 300))
    diameters = np.array(diameters)
    assert diameters.max() <= max_m
    tail = np.exp(-max_m / scale_m)
    truncated_mean = scale_m - max_m * tail / (1.0 - tail)
    assert diameters.mean() == pytest.approx(truncated_mean, abs=4 * scale_m / np.sqrt(diameters.size))
    assert np.mean(radii2) == pytest.approx(0.5 * aperture**2, rel=4 / np.sqrt(len(radii2)))
    # the clear aperture holds the beam of the corner pixel: d tan(corner field angle) + R
    corner_tan = np.hypot(511.5, 511.5) / FOCAL_PX
    assert dust.clear_aperture_radius_m(PINHOLE, distance) == pytest.approx(distance * corner_tan + PUPIL_RADIUS_M,
                                                                             rel=1e-6)

    particles = dust.draw_particles(CAMERA, np.random.default_rng(5), 40, scale_m, max_m, distance)
    combined = dust.transmission_map_exact(CAMERA, particles, distance)
    product = np.ones_like(combined)
    for k in range(particles.diameters_m.size):
        single = dust.DustParticles(particles.positions_m[k:k + 1], particles.diameters_m[k:k + 1])
        product *= dust.transmission_map_exact(CAMERA, single, distance)
    assert np.allclose(combined, product, atol=1e-6) and combined.min() < 0.999


def test_node_grid_transmission_matches_the_per_pixel_map():
    """The interpolated map (one pass per case) against the per-pixel evaluation: 100-particle populations
    at the nightly sweep's sizes, max |difference| below 2e-3 (0.2 % of the light), mean below 1e-4."""
    for seed in range(2):
        particles = dust.draw_particles(CAMERA, np.random.default_rng(seed), 100, 150e-6, 1e-3, 8e-3)
        fast = dust.transmission_map(CAMERA, particles, 8e-3)
        exact = dust.transmission_map_exact(CAMERA, particles, 8e-3)
        assert exact.min() < 0.9                          # the populations do shadow the image
        difference = np.abs(fast.astype(np.float64) - exact)
        assert difference.max() < 2e-3 and difference.mean() < 1e-4


def _pairwise_numpy_map(camera, particles, distance_m):
    """Reference of the node-grid map: every particle against every node (no boxes) in numpy, the blocked
    fraction from :func:`dust.overlap_area`, the logs summed particle by particle, the full-size resize cropped."""
    x, y, _ = dust._node_beam_centres_m(camera, distance_m)
    pupil = dust.entrance_pupil_radius_m(camera)
    log_sum = np.zeros(x.shape)
    for (position_x, position_y), diameter in zip(particles.positions_m, particles.diameters_m):
        separation = np.hypot(x - position_x, y - position_y)
        overlapping = separation < pupil + 0.5 * diameter
        blocked = dust.overlap_area(pupil, 0.5 * diameter, separation[overlapping]) / (np.pi * pupil**2)
        with np.errstate(divide="ignore"):
            log_sum[overlapping] += np.log(np.clip(1.0 - blocked, 0.0, 1.0))
    nodes = np.exp(log_sum).astype(np.float32)
    step = dust.NODE_STEP_PX
    full = cv2.resize(nodes, (nodes.shape[1] * step, nodes.shape[0] * step), interpolation=cv2.INTER_LINEAR)
    return full[step:step + camera.height_px, step:step + camera.width_px]


@pytest.mark.parametrize("seed, count, diameter_scale_m, diameter_max_m", [
    (11, 100, 150e-6, 1e-3), (12, 250, 150e-6, 1e-3), (13, 40, 600e-6, 4e-3)])   # the last with black cores
def test_node_grid_map_equals_the_pairwise_numpy_sums(seed, count, diameter_scale_m, diameter_max_m):
    """The compiled passes (boxes, core / band split, numpy lens areas, sums in particle order) give the bits of
    the plain every-pair numpy evaluation of the same node grid."""
    particles = dust.draw_particles(CAMERA, np.random.default_rng(seed), count, diameter_scale_m, diameter_max_m,
                                    8e-3)
    fast = dust.transmission_map(CAMERA, particles, 8e-3)
    reference = _pairwise_numpy_map(CAMERA, particles, 8e-3)
    assert fast.dtype == np.float32 and fast.flags.c_contiguous and fast.shape == (1024, 1024)
    assert reference.min() < 0.9
    if diameter_scale_m > 200e-6:
        assert reference.min() == 0.0                     # a black core (particle wider than the pupil)
    assert np.array_equal(fast, reference)


def test_compiled_passes_give_the_closed_form_blocked_fraction():
    """One particle against nodes at chosen separations: the core blocks the particle's (or the beam's) whole
    disc, the band the lens area (the classic chord form, not the code's), nothing beyond the reach."""
    from simulator.off_nominal.dust_pairs import node_log_sums, overlapping_nodes

    pupil = 0.6e-3
    pupil_area = np.pi * pupil**2
    for radius in (0.2e-3, 0.9e-3):
        separations = np.array([0.0, 0.5, 0.99, 1.01, 1.3, 1.7, 1.99, 2.01, 3.0]) * abs(pupil - radius)
        separations = np.concatenate([separations, np.linspace(abs(pupil - radius), pupil + radius, 41)[1:-1],
                                      [pupil + radius, 1.2 * (pupil + radius)]])
        x = (separations + 2e-3)[None, :]                 # one row of node beams, the particle at (2 mm, 1 mm)
        y = np.full_like(x, 1e-3)
        separations = np.hypot(x[0] - 2e-3, y[0] - 1e-3)  # as placed (rounding of the sums)
        with np.errstate(divide="ignore"):                # the black core of the wide particle: log 0
            core_log = np.log(np.clip(np.array([1.0 - min(radius, pupil) ** 2 / pupil**2]), 0.0, 1.0))
        core_nodes, core_end, band_nodes, band_terms, band_end = overlapping_nodes(
            x, y, np.array([[2e-3, 1e-3]]), np.array([radius]), pupil, np.array([0]), np.array([0]), np.array([1]),
            np.array([0]), np.array([x.size]))
        band_log = dust._band_log_transmission(band_terms, pupil, pupil_area)
        transmission = np.exp(node_log_sums(x.size, core_log, core_nodes, core_end, band_nodes, band_log, band_end))
        # lens of crossing circles: the common chord at distance d1 from the pupil's centre, d2 from the particle's
        core = separations <= abs(pupil - radius)
        band = ~core & (separations < pupil + radius)
        s = separations[band]
        d1 = (s**2 + pupil**2 - radius**2) / (2 * s)
        d2 = s - d1
        lens = (pupil**2 * np.arccos(d1 / pupil) - d1 * np.sqrt(pupil**2 - d1**2)
                + radius**2 * np.arccos(d2 / radius) - d2 * np.sqrt(radius**2 - d2**2))
        expected = np.ones(separations.size)
        expected[core] = 1.0 - min(radius, pupil) ** 2 / pupil**2
        expected[band] = 1.0 - lens / pupil_area
        assert core.sum() >= 3 and band.sum() >= 40 and (~core & ~band).sum() >= 2
        assert np.allclose(transmission, expected, rtol=0.0, atol=1e-9)
        assert core_nodes.size == core.sum() and band_nodes.size == band.sum()
        assert np.all(transmission[separations >= pupil + radius] == 1.0)


def test_particles_off_the_frame_or_none_leave_the_map_clear():
    far = dust.DustParticles(np.array([[0.05, 0.05], [-0.04, 0.0]]), np.array([300e-6, 300e-6]))
    none = dust.DustParticles(np.zeros((0, 2)), np.zeros(0))
    for particles in (far, none):
        transmission = dust.transmission_map(CAMERA, particles, 8e-3)
        assert transmission.dtype == np.float32 and transmission.shape == (1024, 1024)
        assert np.all(transmission == 1.0)


def test_dust_darkens_the_photoelectron_rate_after_falloff():
    radiance = np.full((1024, 1024), 40.0, dtype=np.float32)
    particles = dust.DustParticles(np.array([[0.0, 0.0]]), np.array([400e-6]))
    transmission = dust.transmission_map(CAMERA, particles, 8e-3)
    effects = NOISE_FREE.model_copy(update=dict(smear=False, dark_current=False, prnu=False))
    clean = render_image(CAMERA, [radiance] * 3, np.random.default_rng(0), effects)
    dirty = render_image(CAMERA, [radiance] * 3, np.random.default_rng(0), effects,
                         OffNominalArtefacts(dust_transmission=transmission))
    expected = clean.expected_charge_e * transmission.reshape(256, 4, 1024).mean(axis=1)
    assert np.allclose(dirty.expected_charge_e, expected, rtol=1e-5)


# ---------------------------------------------------------------- hot pixels

def test_hot_pixel_fraction_and_amplitude_distribution():
    fraction, mean_rate = 2e-3, 5e5
    hot = hot_pixels.draw_hot_pixels(CAMERA, np.random.default_rng(1), fraction, mean_rate)
    pixels = 1024 * 1024
    count = hot.flat_index.size
    assert abs(count - fraction * pixels) < 4 * np.sqrt(pixels * fraction * (1 - fraction))
    assert np.unique(hot.flat_index).size == count and hot.flat_index.max() < pixels
    # MER: CCD at the 0 C reference temperature -> amplitudes as configured (exponential: sigma = mean)
    assert hot.rate_e_per_s.mean() == pytest.approx(mean_rate, abs=4 * mean_rate / np.sqrt(count))
    assert np.median(hot.rate_e_per_s) == pytest.approx(mean_rate * np.log(2), rel=0.08)
    # dark-current rule: one doubling temperature warmer doubles every amplitude
    electronics = CAMERA.electronics
    warm = replace(CAMERA, electronics=electronics.model_copy(update={
        "ccd_temperature_c": electronics.ccd_temperature_c + electronics.dark_doubling_temperature_k}))
    warm_hot = hot_pixels.draw_hot_pixels(warm, np.random.default_rng(1), fraction, mean_rate)
    assert np.allclose(warm_hot.rate_e_per_s, 2.0 * hot.rate_e_per_s, rtol=1e-6)


def test_hot_pixel_adds_its_rate_times_the_exposure_without_smear():
    radiance = np.full((1024, 1024), 30.0, dtype=np.float32)
    hot = hot_pixels.HotPixels(np.array([300 * 1024 + 77], dtype=np.int64), np.array([2.0e6], dtype=np.float32))
    effects = NOISE_FREE.model_copy(update=dict(smear=False))
    base = render_image(CAMERA, [radiance] * 3, np.random.default_rng(0), effects)
    spiked = render_image(CAMERA, [radiance] * 3, np.random.default_rng(0), effects, OffNominalArtefacts(hot_pixels=hot))
    difference = spiked.expected_charge_e.astype(np.float64) - base.expected_charge_e
    assert difference[75, 77] == pytest.approx(2.0e6 * CAMERA.timing.exposure_s, rel=1e-4)
    difference[75, 77] = 0.0
    assert np.abs(difference).max() < 1e-2
    # with smear the hot pixel also streaks along its column (flush + transfer)
    streaked = render_image(CAMERA, [radiance] * 3, np.random.default_rng(0), NOISE_FREE, OffNominalArtefacts(hot_pixels=hot))
    nominal = render_image(CAMERA, [radiance] * 3, np.random.default_rng(0), NOISE_FREE)
    column = streaked.expected_charge_e[:, 77].astype(np.float64) - nominal.expected_charge_e[:, 77]
    assert np.all(column > 0.5) and column[75] > 100 * column[0]


# ---------------------------------------------------------------- particle hits

def test_particle_hit_count_matches_rate_times_area_times_window():
    rate = 100.0
    area_cm2 = (1024 * 12e-4) ** 2
    timing = CAMERA.timing
    window_s = timing.fast_flush_s / 2 + timing.exposure_s + timing.frame_transfer_s + timing.readout_s / 2
    expected = rate * area_cm2 * window_s                       # ~17 hits per image
    assert particle_hits.expected_count(CAMERA, rate) == pytest.approx(expected, rel=1e-12)
    counts = [particle_hits.draw_particle_hits(CAMERA, np.random.default_rng(seed), rate, 1e8, 10e-6, 300e-6).count
              for seed in range(400)]
    assert np.mean(counts) == pytest.approx(expected, abs=4 * np.sqrt(expected / 400))
    assert np.var(counts) == pytest.approx(expected, rel=0.35)   # Poisson: variance = mean


def test_particle_hit_rows_follow_the_readout_wait():
    # read-out dominated window: hits land with density ~ (N - row): mean row N / 3
    slow = replace(CAMERA, timing=CAMERA.timing.model_copy(update=dict(fast_flush_s=0.0, exposure_s=1e-9,
                                                                       frame_transfer_s=0.0, readout_s=1.0)))
    rows = particle_hits.draw_rows(slow, np.random.default_rng(2), 200_000)
    assert rows.mean() == pytest.approx(1024 / 3, abs=4 * 1024 / np.sqrt(18 * 200_000))
    flipped = replace(slow, timing=slow.timing.model_copy(update={"transfer_direction": "toward_first_row"}))
    assert particle_hits.draw_rows(flipped, np.random.default_rng(2), 200_000).mean() == pytest.approx(
        1024 * 2 / 3, abs=2.0)


def test_track_charge_is_conserved_and_lost_only_off_the_array():
    start = np.array([[100.2, 200.7], [500.0, 500.0], [-10.0, 50.5]])
    delta = np.array([[13.0, -7.5], [0.0, 0.0], [20.0, 0.0]])
    charge = np.array([3000.0, 1000.0, 2000.0])
    rows, cols, summed = particle_hits.deposit_tracks((1024, 1024), start, delta, charge)
    assert summed.sum() == pytest.approx(3000.0 + 1000.0 + 1000.0, rel=1e-12)   # half of track 3 is off the array
    assert np.unique(rows * 1024 + cols).size == rows.size
    assert summed[(rows == 500) & (cols == 500)][0] == pytest.approx(1000.0)    # a vertical hit: one pixel
    # the slanted track covers the pixels along its line, ~ its length in pixels of them
    on_first = (rows >= 190) & (rows <= 201) & (cols >= 100) & (cols <= 113)
    assert summed[on_first].sum() == pytest.approx(3000.0) and 14 <= on_first.sum() <= 25


def test_particle_hit_charge_reaches_the_binned_image():
    hits = particle_hits.draw_particle_hits(CAMERA, np.random.default_rng(4), 500.0, 1e8, 10e-6, 300e-6)
    radiance = np.full((1024, 1024), 30.0, dtype=np.float32)
    base = render_image(CAMERA, [radiance] * 3, np.random.default_rng(0), NOISE_FREE)
    hit = render_image(CAMERA, [radiance] * 3, np.random.default_rng(0), NOISE_FREE, OffNominalArtefacts(particle_hits=hits))
    added = hit.expected_charge_e.astype(np.float64) - base.expected_charge_e
    assert hits.count > 50
    assert added.sum() == pytest.approx(hits.charge_e.sum(), rel=1e-4)
    # every hit carries at least the vertical-incidence charge of the collection depth (1000 e-), capped paths at most
    assert hits.charge_e.sum() / hits.count > 1000.0 * 0.97
    assert hits.charge_e.sum() / hits.count < 1e8 * np.hypot(300e-6, 10e-6)


# ---------------------------------------------------------------- blooming

def test_blooming_conserves_charge():
    rng = np.random.default_rng(6)
    full_well = 1000.0
    charge = rng.uniform(0, 900, (64, 48)).astype(np.float32)
    spots = rng.integers(0, 64 * 48, 30)
    charge.reshape(-1)[spots] = rng.uniform(1500, 30000, 30).astype(np.float32)
    bloomed, lost = blooming.bloom_columns(charge, full_well)
    assert bloomed.max() <= full_well
    assert float(bloomed.sum(dtype=np.float64)) + lost == pytest.approx(float(charge.sum(dtype=np.float64)), rel=1e-6)
    untouched = ~np.isin(np.arange(48), spots % 48)
    assert np.array_equal(bloomed[:, untouched], charge[:, untouched])       # no spill across columns


def test_single_saturated_pixel_spills_symmetrically_and_runs_off_the_ends():
    full_well = 100.0
    charge = np.full((41, 3), 20.0)
    charge[20, 1] = 100.0 + 2 * 200.0                    # 400 e- excess: 200 up, 200 down, 80 fill each pixel
    bloomed, lost = blooming.bloom_columns(charge, full_well)
    column = bloomed[:, 1]
    assert lost == 0.0 and column[20] == 100.0
    assert np.allclose(column[17:20], [60.0, 100.0, 100.0]) and np.allclose(column[21:24], [100.0, 100.0, 60.0])
    assert np.allclose(column[:17], 20.0) and np.allclose(column[24:], 20.0)
    assert np.allclose(column, column[::-1])
    near_edge = np.full((10, 1), 0.0)
    near_edge[1, 0] = 100.0 + 1000.0                     # 500 up: 100 fills row 0, 400 run off; 500 down: rows 2..6
    bloomed, lost = blooming.bloom_columns(near_edge, full_well)
    assert lost == pytest.approx(400.0) and np.allclose(bloomed[:, 0], [100] * 7 + [0] * 3)


def test_nothing_changes_without_saturation_and_blooming_switch_in_the_chain():
    charge = np.random.default_rng(0).uniform(0, 99, (20, 20)).astype(np.float32)
    bloomed, lost = blooming.bloom_columns(charge, 100.0)
    assert bloomed is charge and lost == 0.0
    radiance = np.full((1024, 1024), 30.0, dtype=np.float32)
    radiance[500:502, 600] = 6000.0                      # ~5.7e6 e- per pixel: 30 full wells
    effects = NOISE_FREE.model_copy(update=dict(smear=False, dark_current=False, optics_psf=False))  # a sharp spike
    bloomed = render_image(CAMERA, [radiance] * 3, np.random.default_rng(0), effects).expected_charge_e
    clipped = render_image(CAMERA, [radiance] * 3, np.random.default_rng(0), effects,
                           OffNominalArtefacts(blooming=False)).expected_charge_e
    column = bloomed[:, 600] - clipped[:, 600]
    assert column[118:133].min() > 1.5 * CAMERA.electronics.full_well_e          # a bright streak
    assert np.count_nonzero(column > 1.0) >= 10 and abs(np.argmax(column > 1) + np.max(np.nonzero(column > 1)) - 250) <= 2
    assert np.allclose(bloomed[:, 599], clipped[:, 599]) and np.allclose(bloomed[:, 601], clipped[:, 601])
