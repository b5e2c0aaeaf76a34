"""Running cases: the case computation (:mod:`.case`), worker setup, the dask runner and its cluster
backends, faults, progress, and the one orchestration path of ``submit`` and ``sweep``
(:mod:`.orchestrate`, :mod:`.sweep`)."""
