"""Progress of a campaign run on stderr: a tqdm bar on a terminal, plain periodic lines otherwise.

On a terminal (``isatty()`` of the stream actually written to): one tqdm bar with the case rate, the
ETA and the failed count in its postfix. Anywhere else (a log file, a pipe, a CI job): one plain line
every ``interval_s`` (5 s) while the run goes on, and one at the end, e.g.::

    cases 12/40 (1 failed), 0.41 cases/s, elapsed 29 s, ETA 68 s
"""
from __future__ import annotations

import os
import sys
import time

from tqdm import tqdm

from campaign.run.interrupts import interrupting

DEFAULT_COLUMNS = 100   # bar width on a terminal that reports no size (0 x 0, e.g. a fresh pty)
DEFAULT_ROWS = 24       # tqdm draws nothing on a terminal of 0 rows


def _terminal_columns(stream) -> int:
    try:
        return os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, ValueError, OSError):
        return 0


def is_terminal(stream) -> bool:
    """True when ``stream`` is a terminal (a closed or fake stream is not)."""
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False


class ProgressBar:
    """Progress of ``total`` cases written to ``stream`` (default: sys.stderr at construction time)."""

    def __init__(self, total: int, enabled: bool = True, stream=None, interval_s: float = 5.0):
        self.total = total
        self.enabled = enabled and total > 0
        self.stream = sys.stderr if stream is None else stream
        self.tty = is_terminal(self.stream)          # the stream written to, not the argument
        self.interval_s = interval_s
        self.start = time.perf_counter()
        self.last_line = self.start
        self.count = 0
        self.bar = None
        if self.enabled and self.tty:
            sized = _terminal_columns(self.stream) > 0       # a fresh pty may report 0 columns
            self.bar = tqdm(total=total, file=self.stream, unit="case", desc="cases", dynamic_ncols=sized,
                            ncols=None if sized else DEFAULT_COLUMNS, nrows=None if sized else DEFAULT_ROWS,
                            smoothing=0.1, mininterval=0.5)
            self.bar.set_postfix(failed=0, refresh=False)

    def update(self, count: int, failed: int = 0) -> None:
        """``count`` cases finished so far, ``failed`` of them failed (call often: also the clock)."""
        if not self.enabled:
            return
        now = time.perf_counter()
        if self.bar is not None:
            if count != self.count:
                self.bar.set_postfix(failed=failed, refresh=False)
                self.bar.update(count - self.count)
            elif now - self.last_line >= 1.0:
                self.bar.refresh()              # elapsed time and rate move on while no case finishes
                self.last_line = now
            self.stream.flush()
        elif now - self.last_line >= self.interval_s:
            self._line(count, failed)
        self.count = count

    def close(self, count: int | None = None, failed: int = 0) -> None:
        """End the progress: the bar's last state, or a last plain line (none when a stop signal ends the run:
        its one line says what was kept, :mod:`campaign.run.interrupts`)."""
        if not self.enabled:
            return
        if interrupting() and self.bar is None:
            self.enabled = False
            return
        count = self.count if count is None else count
        if self.bar is not None:
            if count != self.count:
                self.bar.set_postfix(failed=failed, refresh=False)
                self.bar.update(count - self.count)
            self.bar.close()
            self.bar = None
            self.stream.flush()
        else:
            self._line(count, failed)
        self.enabled = False

    def _line(self, count: int, failed: int) -> None:
        now = time.perf_counter()
        elapsed = max(now - self.start, 1e-9)
        rate = count / elapsed
        eta = f"{(self.total - count) / rate:.0f} s" if rate > 0 else "unknown"
        self.stream.write(f"cases {count}/{self.total} ({failed} failed), {rate:.2f} cases/s, "
                          f"elapsed {elapsed:.0f} s, ETA {eta}\n")
        self.stream.flush()
        self.last_line = now
