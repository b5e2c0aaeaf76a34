"""What a rendered descent image reports about itself, against numpy's own answers."""
from __future__ import annotations

import numpy as np
import pytest

from simulator.descent_image import DescentImage


@pytest.mark.parametrize("shape", [(1024, 1024), (3, 7), (1, 1), (257, 1031)])
@pytest.mark.parametrize("density", [0.0, 1e-6, 0.37, 1.0])
def test_the_outside_terrain_fraction_is_the_mask_s_mean_bit_for_bit(shape, density):
    mask = np.random.default_rng(int(density * 1e6) + shape[0]).random(shape) < density
    image = DescentImage(image=None, radiance=None, sky_mask=mask, outside_terrain_mask=mask, heat_shield_mask=mask,
                         diagnostics=None)
    fraction = image.outside_terrain_fraction
    assert isinstance(fraction, float)
    assert np.float64(fraction).view(np.uint64) == np.float64(mask.mean()).view(np.uint64)
