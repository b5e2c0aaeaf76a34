"""``campaign plan``'s footprint maps: one PNG per class (paper Fig. 5)."""
from __future__ import annotations

from pathlib import Path

import pandas as pd

from campaign.case.inputs import PlanRow, SiteInputs
from campaign.configuration.campaign_file import CampaignConfig
from campaign.plan.density import footprint_density
from campaign.report.plots import footprint_map

FOOTPRINTS_DRAWN = 60   # outlines drawn on a footprint map; every case is in its density layer


def write_plan_maps(config: CampaignConfig, site: SiteInputs, plan: pd.DataFrame, out_dir: Path) -> list[Path]:
    """One footprint map PNG per class of ``plan`` in ``out_dir`` (created): the first
    :data:`FOOTPRINTS_DRAWN` cases' outlines over the terrain, the footprint centres of all as a density.
    ``site``: the campaign's loaded inputs (:func:`campaign.run.planning.plan_campaign`). Returns the paths."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for class_name, members in plan.groupby("class_name", sort=False):
        terrain = site.terrain(str(class_name))
        drawn = members.head(FOOTPRINTS_DRAWN)      # outlines of the first cases; all cases as a density
        placed = [site.placed_profile(PlanRow.from_record(row)) for row in drawn.to_dict("records")]
        density = footprint_density(site.camera, site.profiles, members, terrain.extent_m)
        path = out_dir / f"footprints-{class_name}.png"
        footprint_map(terrain, placed, site.camera, path,
                      f"{config.site.name} {class_name}: {len(members)} cases\nfirst {len(drawn)}: + lander at each "
                      "image,\noutlines: images 1/2/3 red/orange/cyan\nshading: footprint centres, all cases",
                      max_cases=FOOTPRINTS_DRAWN, density=density)
        paths.append(path)
    return paths
