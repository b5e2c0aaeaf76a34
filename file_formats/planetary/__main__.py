"""``python -m file_formats.planetary``: the short spelling of ``python -m file_formats.planetary.inspect_files``."""
import sys

from file_formats.planetary.inspect_files import main

if __name__ == "__main__":
    sys.exit(main())
