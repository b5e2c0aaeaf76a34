"""The old path of ``python -m campaign.realism.measure_terrains`` (scripts may run ``python -m campaign.realism.terrain_stats_cli``)."""
import sys

from campaign.realism.measure_terrains import main

if __name__ == "__main__":
    sys.exit(main())
