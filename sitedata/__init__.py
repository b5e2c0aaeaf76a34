"""Site data: Gusev and Meridiani sites, cameras, EDL trajectory sets, terrain sources and readers."""
