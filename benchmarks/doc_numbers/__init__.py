"""Measured numbers of the README and docs/ from one record.

Every measured figure the pages quote lives once, with its date and source, in ``docs/measured/``; a page
quotes it through a generated block (``<!-- measured:begin KEY -->...<!-- measured:end -->``) that
``python -m benchmarks.doc_numbers write`` rewrites from the record and ``check`` compares with it
(``tests/test_documented_numbers.py`` runs it). One idea per module:

- :mod:`~benchmarks.doc_numbers.record`: the record (``facts.csv``, the site, paper and recorded tables) read,
  validated and written;
- :mod:`~benchmarks.doc_numbers.tables`: the tables generated from it (sites, fidelity presets, speed-up);
- :mod:`~benchmarks.doc_numbers.blocks`: the blocks of the pages rendered, checked and rewritten, and the
  superseded figures a page may no longer quote;
- :mod:`~benchmarks.doc_numbers.importers`: feeding the record from a ``make bench`` CSV and from finished
  campaign stores;
- :mod:`~benchmarks.doc_numbers.cli`: the command line (``check``, ``write``, ``import-bench``,
  ``campaign-table``, ``list``), run as ``python -m benchmarks.doc_numbers``.

The package uses the standard library only (and the one-line parser of ``config_tables``), so checking the
pages imports nothing of the simulator or the campaign.
"""
