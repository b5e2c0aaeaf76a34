"""Compile the case code's numba passes into the checkout's cache once, before the test processes start.

``python tests/numba_warmup.py DONE_FILE`` computes one case of each class of sitedata/gusev.toml (``--cases-scale
0.005``: three cases) in this process, the way a campaign worker does (``campaign.case.compute.compute_case``),
then writes DONE_FILE. The passes are ``numba.njit(cache=True)``: compiled at their first call and written under
``__pycache__`` beside their module; a process that starts after that loads them from the cache in milliseconds.
Without this, on a clean clone, each of the two pytest-xdist processes and each worker of their warm clusters
(tests/conftest.py) compiles the same passes at the same time (about 10-20 s CPU each on the 2-core machine).

Run by tests/conftest.py from the controlling pytest process; what it computes is not checked here (a broken case
path fails the tests that check it), and whatever happens, DONE_FILE is written so that nobody waits for ever.
"""
from __future__ import annotations

import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def warm_up() -> None:
    from campaign.case.compute import compute_case
    from campaign.case.inputs import PlanRow, campaign_inputs
    from campaign.configuration.campaign_file import load_campaign_config
    from campaign.run.planning import plan_campaign

    config = load_campaign_config(REPO / "sitedata" / "gusev.toml", cases_scale=0.005)
    _, plan = plan_campaign(config)
    resources = campaign_inputs(config)
    for record in plan.to_dict("records"):
        compute_case(resources, PlanRow.from_record(record))


if __name__ == "__main__":
    done = Path(sys.argv[1])
    try:
        warm_up()
    finally:
        done.write_text("done\n")
