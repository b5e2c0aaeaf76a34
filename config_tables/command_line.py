"""Command-line contract shared by every command line of the project: the one-line usage-error parser.

A usage or input error is ONE line on stderr naming the file (or flag), the field and what is allowed, exit status
2, and nothing written.
"""
from __future__ import annotations

import argparse

USAGE_ERROR = 2


class OneLineParser(argparse.ArgumentParser):
    """``argparse`` whose usage errors are one line (``prog: error: message``) and exit status 2."""

    def error(self, message: str):
        """Print ``prog: error: message`` as one line on stderr and exit with status 2.

        Parameters
        ----------
        message : str
            The error; its whitespace runs (line breaks included) become single spaces.
        """
        self.exit(USAGE_ERROR, f"{self.prog}: error: {' '.join(message.split())}\n")
