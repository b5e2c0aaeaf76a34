"""``python -m simulator``: the short spelling of ``python -m simulator.render_example`` (same arguments)."""
import sys

from simulator.render_example import main

if __name__ == "__main__":
    sys.exit(main())
