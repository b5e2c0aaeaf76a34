"""The old path of ``python -m sitedata.edl.trajectory_sets`` (scripts may run ``python -m sitedata.edl.trajectories_cli``)."""
import sys

from sitedata.edl.trajectory_sets import main

if __name__ == "__main__":
    sys.exit(main())
