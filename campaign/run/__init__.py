"""Running cases on dask: planning (:mod:`.planning`), the one locked-run path of ``submit`` and ``sweep``
(:mod:`.orchestrate`, :mod:`.sweep`), the worker's task (:mod:`.worker`), the dask runner and its cluster
backends, faults, progress, and the estimator check. The case itself is :mod:`campaign.case`; nothing here
imports :mod:`campaign.report`."""
