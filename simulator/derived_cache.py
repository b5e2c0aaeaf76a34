"""One visible cache of arrays derived from a camera or a terrain, shared by the scene and detector stages.

The arrays: pixel gain, PRNU map, camera-frame rays, terrain mean I/F, orbital haze.

Cameras and terrains are frozen dataclasses holding arrays, hence unhashable: they cannot key a dict or
a ``functools`` cache. :data:`DERIVED` keys each owner by identity and drops its entries when the owner is
garbage-collected (``weakref.finalize``), so nothing is stored on the objects themselves and nothing
derived travels with them when they are pickled to a dask worker.
"""
from __future__ import annotations

import weakref
from typing import Any


class DerivedCache:
    """Derived values per (owner object, stage name); entries live exactly as long as their owner."""

    def __init__(self) -> None:
        self._by_owner: dict[int, dict[str, dict[Any, Any]]] = {}

    def of(self, owner: object, stage: str) -> dict[Any, Any]:
        """The mutable cache dict of ``owner`` for ``stage``.

        Parameters
        ----------
        owner : object
            The camera, terrain or other object the values derive from (keyed by identity).
        stage : str
            Name of the stage that owns the entries (e.g. ``"render"``, ``"scene"``).

        Returns
        -------
        dict
            The cache, created empty on first use and dropped when ``owner`` is garbage-collected.
        """
        entries = self._by_owner.get(id(owner))
        if entries is None:
            entries = self._by_owner[id(owner)] = {}
            weakref.finalize(owner, self._by_owner.pop, id(owner), None)
        return entries.setdefault(stage, {})

    def owners(self) -> int:
        """How many live objects hold cached values.

        Returns
        -------
        int
            Number of owners with a cache entry.
        """
        return len(self._by_owner)


#: The simulator's one cache of derived arrays.
DERIVED = DerivedCache()
