"""One Monte Carlo case, below both running and reporting: the planned row (:mod:`.plan_row`), the inputs a
process loads once (:mod:`.site` for what planning needs, :mod:`.inputs` for the whole campaign), the
case computation and its truth (:mod:`.compute`), its result rows (:mod:`.result_rows`), and a case's
inputs as files (:mod:`.export`). :mod:`campaign.run` runs cases on dask with these; :mod:`campaign.report`
simulates cases again with them for the failure gallery."""
