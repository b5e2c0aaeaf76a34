"""The campaign store: one directory per campaign, durable per-case files with their integrity records,
one writer at a time (:mod:`.lock`), compaction into ``results.parquet``, ``campaign verify``, a sweep's
sweep.json (:mod:`.sweep_directory`) and the configuration a store was computed with (:mod:`.stored_config`)."""
