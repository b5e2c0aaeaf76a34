"""Reading a store for people: the paper's tables (:mod:`.aggregate`, :mod:`.table`), estimators side by side
(:mod:`.compare`), the Markdown report (:mod:`.markdown`) with its plots and failure gallery, the plan's
footprint maps, a sweep's outputs and its baseline check. Written after a run by the command line; nothing
here imports :mod:`campaign.run`."""
