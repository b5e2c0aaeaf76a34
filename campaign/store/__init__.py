"""The campaign store: one directory per campaign, durable per-case files with their integrity records,
one writer at a time (:mod:`.lock`), compaction into ``results.parquet``, and ``campaign verify``."""
