"""The compiled unprojection of the warp's checks against flight_interface.cahvor.unproject, bit for bit."""
import numpy as np
import pytest

from flight_interface import cahvor
from flight_interface.camera import load_camera
from simulator.scene import unproject_compiled


def _models():
    """Descent-camera-like and tilted, skewed models: no distortion, barrel (with a turning point), pincushion."""
    rng = np.random.default_rng(3)
    models = [cahvor.cahvor_from_intrinsics(0.01467, 12e-6, (511.5, 511.5), (0.0, -0.01, 0.0)),
              cahvor.cahvor_from_intrinsics(0.01467, 12e-6, (511.5, 511.5)),
              cahvor.cahvor_from_intrinsics(0.01, 12e-6, (500.0, 520.0), (0.001, 0.02, 0.001))]
    for _ in range(6):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        optical = axis + rng.normal(0.0, 0.01, 3)
        optical /= np.linalg.norm(optical)
        focal = rng.uniform(300.0, 3000.0)
        models.append(cahvor.Cahvor(c=rng.normal(size=3), a=axis, h=focal * rng.normal(size=3) + 511.5 * axis,
                                    v=focal * rng.normal(size=3) + 511.5 * axis, o=optical,
                                    r=np.array([rng.normal(0, 0.05), rng.normal(0, 0.05), rng.normal(0, 0.01)])))
    return models


@pytest.mark.parametrize("model", _models())
def test_compiled_unprojection_gives_the_array_codes_bits(model):
    rng = np.random.default_rng(11)
    centre = np.array([model.hc, model.vc])
    sets = [centre, centre[None, :], np.zeros((0, 2)), rng.uniform(-2000.0, 3000.0, (5, 25, 2)),
            rng.uniform(0.0, 1024.0, (130, 2)), rng.uniform(-5000.0, 6000.0, (40, 2)),
            np.array([[np.nan, 3.0], [np.inf, 1.0], [centre[0], centre[1]]])]
    for pixels in sets:
        with np.errstate(all="ignore"):
            expected = cahvor.unproject(model, pixels)
        rays = unproject_compiled.unproject(model, pixels)
        assert rays.shape == expected.shape
        assert rays.tobytes() == expected.tobytes()


def test_the_newton_steps_are_shared_by_the_whole_set_as_in_the_array_code():
    # pairs of far off-axis pixels where the array code gives the first a different ray alone than in the
    # pair (the second's extra Newton steps move it in the last bit): the compiled rays of the pair must be
    # the array code's, so the step count is the set's, not each pixel's
    model = cahvor.cahvor_from_intrinsics(0.01467, 12e-6, (511.5, 511.5), (0.0, -0.05, 0.01))
    rng = np.random.default_rng(0)
    pairs = []
    with np.errstate(all="ignore"):
        while len(pairs) < 5:
            pair = rng.uniform(-3000.0, 4000.0, (2, 2))
            if cahvor.unproject(model, pair[:1]).tobytes() != cahvor.unproject(model, pair)[:1].tobytes():
                pairs.append(pair)
        for pair in pairs:
            assert unproject_compiled.unproject(model, pair).tobytes() == cahvor.unproject(model, pair).tobytes()
            assert unproject_compiled.unproject(model, pair[:1]).tobytes() == cahvor.unproject(model, pair[:1]).tobytes()


def test_compiled_rays_project_back_onto_their_pixels():
    model = cahvor.cahvor_from_intrinsics(0.01467, 12e-6, (511.5, 511.5), (0.0, -0.01, 0.0))
    pixels = np.random.default_rng(5).uniform(0.0, 1023.0, (50, 2))
    projected, in_front = cahvor.project(model, unproject_compiled.unproject(model, pixels))
    assert in_front.all()
    np.testing.assert_allclose(projected, pixels, atol=1e-6)


def test_primed_pixel_rays_are_the_camera_s_own_bit_for_bit(mer_a_path):
    primed, own = load_camera(mer_a_path), load_camera(mer_a_path)
    unproject_compiled.prime_pixel_rays(primed)
    assert "pixel_rays" in vars(primed) and "pixel_rays" not in vars(own)
    assert primed.pixel_rays.shape == (own.height_px, own.width_px, 3)
    assert primed.pixel_rays.tobytes() == own.pixel_rays.tobytes()      # own: cahvor.unproject, the array code
    assert not primed.pixel_rays.flags.writeable
    assert primed.falloff_map.tobytes() == own.falloff_map.tobytes()
    kept = primed.pixel_rays
    unproject_compiled.prime_pixel_rays(primed)                         # held already: left as it is
    unproject_compiled.prime_pixel_rays(own)
    assert primed.pixel_rays is kept and own.pixel_rays.tobytes() == kept.tobytes()
