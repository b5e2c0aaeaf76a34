"""``python -m benchmarks.doc_numbers``: the command line of :mod:`benchmarks.doc_numbers.cli`."""
import sys

from benchmarks.doc_numbers.cli import main

if __name__ == "__main__":
    sys.exit(main())
