"""Progress on stderr (tqdm on a terminal, plain periodic lines elsewhere) and the dask dashboard that
`campaign submit` links to, during a real run: the page is served by bokeh, not "Dask needs bokeh"."""
from __future__ import annotations

import os
import re
import select
import subprocess
import sys
import time
import urllib.request

import pytest

from campaign.run.progress import ProgressBar
from service_campaigns import REPO, campaign_command, campaign_file

PLAIN_LINE = re.compile(r"^cases (\d+)/(\d+) \((\d+) failed\), \d+\.\d\d cases/s, elapsed \d+ s, ETA (\d+ s|unknown)$")


def _read_available(descriptor: int, wait_s: float = 0.5) -> str:
    """What a pty's other side wrote, until it is quiet for ``wait_s`` (data arrives in pieces)."""
    chunks = []
    while select.select([descriptor], [], [], wait_s)[0]:
        try:
            data = os.read(descriptor, 65536)
        except OSError:          # EIO: the other side of the pty is closed
            break
        if not data:
            break
        chunks.append(data)
    return b"".join(chunks).decode(errors="replace")


def test_terminal_gets_a_tqdm_bar_with_rate_eta_and_failed_count():
    controller, terminal = os.openpty()
    stream = open(terminal, "w", closefd=True)
    try:
        bar = ProgressBar(4, stream=stream)
        assert bar.tty
        bar.update(1, 0)
        bar.update(3, 1)
        bar.close(4, 1)
        text = _read_available(controller)
    finally:
        stream.close()
        os.close(controller)
    assert "\r" in text and "cases: 100%" in text and "4/4" in text, text
    assert "failed=1" in text and re.search(r"case/s|s/case", text) and "<00:00" in text, text


def test_the_stream_checked_for_a_terminal_is_the_one_written_to(monkeypatch, tmp_path):
    """The old bug: isatty() asked of the constructor argument (None) instead of sys.stderr."""
    controller, terminal = os.openpty()
    try:
        with open(terminal, "w", closefd=True) as stream:
            monkeypatch.setattr(sys, "stderr", stream)
            assert ProgressBar(4, enabled=False).tty and ProgressBar(4, enabled=False).stream is stream
        with open(tmp_path / "log", "w") as stream:
            monkeypatch.setattr(sys, "stderr", stream)
            assert not ProgressBar(4, enabled=False).tty
    finally:
        os.close(controller)


def test_file_or_pipe_gets_plain_periodic_lines_and_a_last_line(tmp_path):
    path = tmp_path / "progress.log"
    with open(path, "w") as stream:
        bar = ProgressBar(4, stream=stream, interval_s=0.2)
        assert not bar.tty
        bar.update(1, 0)                    # before the interval: nothing
        time.sleep(0.25)
        bar.update(2, 1)                    # a periodic line
        time.sleep(0.25)
        bar.update(2, 1)                    # the clock alone also writes one (nothing finished meanwhile)
        bar.close(4, 1)
    lines = path.read_text().splitlines()
    assert "\r" not in path.read_text() and len(lines) == 3, lines
    matches = [PLAIN_LINE.match(line) for line in lines]
    assert all(matches), lines
    assert [match.group(1, 2, 3) for match in matches] == [("2", "4", "1"), ("2", "4", "1"), ("4", "4", "1")]
    assert matches[-1].group(4) == "0 s"


@pytest.mark.cluster
@pytest.mark.slow
def test_submit_links_a_dashboard_serving_the_task_stream_and_shows_tqdm_on_a_terminal(tmp_path):
    path = campaign_file(tmp_path, {"gcp": 3, "gdcp": 1, "gkep": 0}, "workers = 1")
    controller, terminal = os.openpty()
    process = subprocess.Popen(campaign_command("submit", path, "--output", tmp_path / "out"), cwd=REPO,
                               stdout=subprocess.PIPE, stderr=terminal, text=True)
    os.close(terminal)
    try:
        first = process.stdout.readline()
        match = re.match(r"dask dashboard: (http://\S+)/status  scheduler: ", first)
        assert match, first
        pages = {}
        for route in ("status", "tasks"):
            with urllib.request.urlopen(f"{match.group(1)}/{route}", timeout=30) as response:
                pages[route] = (response.status, response.read().decode(errors="replace"))
        running = process.poll() is None
        stdout = first + process.stdout.read()
        terminal_text = ""
        while process.poll() is None or not terminal_text.endswith("\n"):
            chunk = _read_available(controller, 1.0)
            if not chunk and process.poll() is not None:
                break
            terminal_text += chunk
    finally:
        process.wait(timeout=300)
        os.close(controller)
    assert process.returncode == 0, stdout + terminal_text
    assert running, "the run ended before the dashboard was read"
    for route, (status, body) in pages.items():
        assert status == 200 and "needs bokeh" not in body, (route, body[:300])
        assert "Bokeh" in body or "bokeh" in body, (route, body[:300])
    assert "Task Stream" in pages["tasks"][1] or "task-stream" in pages["tasks"][1].lower(), pages["tasks"][1][:500]
    assert "\r" in terminal_text and "4/4" in terminal_text and "failed=0" in terminal_text, terminal_text
