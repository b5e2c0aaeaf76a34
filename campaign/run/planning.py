"""Planning a campaign: every class's cases placed on its terrain (``campaign plan``, and the first step of
``submit`` and ``sweep``), loading only what planning needs (:class:`campaign.case.inputs.SiteInputs`: the
camera, the trajectory set and the class terrains; no estimators, calibration or worker set-up)."""
from __future__ import annotations

import pandas as pd

from campaign.case.inputs import SiteInputs
from campaign.configuration.campaign_file import CampaignConfig
from campaign.plan.coverage import refusal, relief_margin_m
from campaign.plan.placement import ClassPlanInput, plan_class
from config_tables.errors import ConfigError


def plan_campaign(config: CampaignConfig) -> tuple[SiteInputs, pd.DataFrame]:
    """Load what planning needs (camera, trajectories, terrain extents) and plan every class.

    Returns
    -------
    site : SiteInputs
        The loaded camera, trajectory set and terrains (the footprint maps draw on them).
    plan : pandas.DataFrame
        One row per planned case (:mod:`campaign.plan.placement`'s columns), classes in site order.

    Raises
    ------
    ConfigError
        One line, for a class whose terrain cannot hold the trajectory set's footprints
        (:mod:`campaign.plan.coverage`), before anything is written.
    """
    site = SiteInputs(config)
    frames = []
    for index, entry in enumerate(config.site.classes):
        count = config.cases_per_class[entry.name]
        if count == 0:
            continue
        terrain = site.terrain(entry.name)
        cover = site.coverage(terrain)
        if not cover.holds:
            raise ConfigError(f"{config.source}: {refusal(entry.name, terrain, cover)}")
        spec = ClassPlanInput(class_name=entry.name, class_index=index, ellipse_fraction=entry.ellipse_fraction,
                              cases=count, terrain_name=terrain.name, terrain_extent_m=terrain.extent_m,
                              margin_m=2.0 * terrain.metres_per_pixel
                              + relief_margin_m(terrain, site.camera, site.profiles))
        frames.append(plan_class(site.camera, site.profiles, spec, config.seed))
    plan = pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
    return site, plan
