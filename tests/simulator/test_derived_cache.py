"""The simulator's one cache of derived arrays: values per owner and stage, gone with their owner, never on
the owner itself (so a pickled camera carries nothing derived)."""
from __future__ import annotations

import gc
import pickle

import numpy as np

from simulator.derived_cache import DERIVED, DerivedCache
from simulator.detector.charge_generation import prnu_map


class Owner:
    """Any object that can be weakly referenced."""


def test_entries_are_per_owner_and_stage_and_die_with_the_owner():
    cache = DerivedCache()
    first, second = Owner(), Owner()
    cache.of(first, "render")["gain"] = 1
    assert cache.of(first, "render") == {"gain": 1}
    assert cache.of(first, "scene") == {} and cache.of(second, "render") == {}
    assert cache.owners() == 2
    del first
    gc.collect()
    assert cache.owners() == 1


def test_a_pickled_camera_carries_nothing_derived(mer_a):
    prnu = prnu_map(mer_a)
    assert prnu_map(mer_a) is prnu                                   # computed once per camera
    falloff = mer_a.falloff_map                                      # a cached property of the camera
    assert not any(isinstance(value, dict) for value in vars(mer_a).values())   # no hidden cache dict
    restored = pickle.loads(pickle.dumps(mer_a))
    assert len(pickle.dumps(mer_a)) < prnu.nbytes / 4                # the 4 MiB map does not travel
    np.testing.assert_array_equal(prnu_map(restored), prnu)          # the same seeded map, recomputed
    np.testing.assert_array_equal(restored.falloff_map, falloff)
    assert DERIVED.owners() >= 2
