"""One Monte Carlo case, below both running and reporting: its inputs (:mod:`.inputs`: the plan row, what
planning needs of the site, the campaign's inputs loaded once per process), the case computation and its
truth (:mod:`.compute`), its result rows (:mod:`.result_rows`), and a case's inputs as files
(:mod:`.export`). :mod:`campaign.run` runs cases on dask with these; :mod:`campaign.report` simulates cases
again with them for the failure gallery."""
