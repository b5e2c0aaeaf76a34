"""Names shared by sweep files and the readers of sweep directories, without the configuration models (the
table and status of a sweep directory import this, not :mod:`campaign.configuration.sweep_file`)."""
from __future__ import annotations

SITE_AXIS = "site"
"""The axis of a sweep of several bases (``[sweep] base = [...]``): a point's base, by its site's name."""
