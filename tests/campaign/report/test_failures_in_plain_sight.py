"""Failed estimator rows in plain sight (issue 32): a Python plug-in that fails three ways in one run (a
RuntimeError whose 700-character message holds a ``|`` and backticks, a NaN velocity declared valid, a
ValueError whose message has a newline). `campaign submit` names every kind with its count and an example whose
file and line survive; the store keeps the full text; the report's Failed cases table has exactly its four
columns on every row; the gallery counts the failed rows. Plus the helpers on hand-made texts."""
from __future__ import annotations

import re
import sys
import textwrap

import pandas as pd
import pytest

from campaign.report.failures import abbreviate_error, failure_kind, failure_summary, markdown_cell
from service_campaigns import campaign_file, campaign_in_process

PLUGIN = "issue32_three_ways"
LONG_MESSAGE = "the matcher diverged | see `trace` " + "x" * 700
PLUGIN_SOURCE = textwrap.dedent(f'''
    """Fails in turn three ways (one worker: its calls are counted in order)."""
    import math

    CALLS = []


    def estimate(inputs):
        CALLS.append(1)
        turn = len(CALLS) % 3
        if turn == 1:
            raise RuntimeError({LONG_MESSAGE!r})
        if turn == 2:
            return {{"velocity_east_mps": math.nan, "velocity_north_mps": 0.0, "valid": True, "reason": "ok"}}
        raise ValueError("bad template\\nsecond line")
''')
LOCATION = re.compile(rf'File "[^"]*{PLUGIN}\.py", line \d+, in estimate$')


def unescaped_pipes(line: str) -> int:
    return len(re.findall(r"(?<!\\)\|", line))


@pytest.fixture(scope="module")
def failing_store(tmp_path_factory):
    """A submitted 3-case Gusev campaign (one worker) with the reference and the three-ways plug-in, reported."""
    directory = tmp_path_factory.mktemp("three_ways")
    (directory / f"{PLUGIN}.py").write_text(PLUGIN_SOURCE)
    config = campaign_file(directory, execution="workers = 1", extra=(
        f'\n[[estimators]]\nname = "dimes"\nkind = "reference"\n\n[[estimators]]\nname = "flaky"\n'
        f'kind = "python"\ncallable = "{PLUGIN}:estimate"\n'))
    out = directory / "out"
    sys.path.insert(0, str(directory))
    try:
        yield directory, config, out
    finally:
        sys.path.remove(str(directory))
        sys.modules.pop(PLUGIN, None)


@pytest.mark.cluster
@pytest.mark.slow
def test_submit_names_every_failure_kind_and_the_store_keeps_the_whole_text(failing_store, capfd):
    directory, config, out = failing_store
    submit = campaign_in_process(capfd, "submit", config, "--output", out, "--no-progress")
    assert submit.returncode == 1, submit.stdout + submit.stderr
    assert "Traceback" not in submit.stderr
    assert "estimator rows failed: flaky 3 (every kind on stderr)" in submit.stdout
    lines = [line for line in submit.stderr.splitlines() if line.startswith("campaign: ")]
    header = lines.index(next(line for line in lines if line.startswith("campaign: estimator flaky: ")))
    assert lines[header].startswith("campaign: estimator flaky: 3 of 3 rows failed, 3 kinds"), lines
    kinds = {line.split(" x ", 1)[1].split(", e.g. ")[0]: line for line in lines[header + 1:header + 4]}
    assert set(kinds) == {"crashed (RuntimeError)", "implausible answer", "crashed (ValueError)"}, lines
    crashed = kinds["crashed (RuntimeError)"]
    assert crashed.startswith("campaign:   1 x crashed (RuntimeError), e.g. case ")
    assert LOCATION.search(crashed), crashed                # abbreviated, but the file and line are whole
    assert len(crashed) < len(LONG_MESSAGE)
    assert "must be finite" in kinds["implausible answer"] and "bad template second line" in kinds["crashed (ValueError)"]
    results = pd.read_parquet(out / "results.parquet")
    stored = results.loc[results["error"].str.contains("RuntimeError", na=False), "error"].item()
    assert LONG_MESSAGE in stored and LOCATION.search(stored), stored      # the full text, file and line kept

    report = campaign_in_process(capfd, "report", out)
    assert report.returncode == 0 and "Traceback" not in report.stderr, report.stderr
    text = (out / "report" / "report.md").read_text()
    section = text.split("### Failed cases")[1].split("\n## ")[0]
    rows = [line for line in section.splitlines() if line.startswith("| ") and not line.startswith("| case")]
    assert len(rows) == 3
    for row in rows:           # case | class | reason | error: five unescaped pipes, one line each
        assert unescaped_pipes(row) == 5, row
        assert re.search(r"line \d+, in estimate", row) or "must be finite" in row, row
    assert any("the matcher diverged \\| see \\`trace\\`" in row for row in rows)
    assert any("bad template<br>second line" in row for row in rows)
    for kind in ("crashed (RuntimeError)", "implausible answer", "crashed (ValueError)"):
        assert f"1 x {kind}" in text, kind
    gallery = (out / "report" / "gallery.md").read_text()
    assert "nothing to show" not in gallery
    assert "## Failed rows" in gallery and "| flaky | 3 of 3 |" in gallery
    for kind in ("crashed (RuntimeError)", "implausible answer", "crashed (ValueError)"):
        assert f"| {kind} | 1 |" in gallery, gallery


def test_failure_kinds_of_hand_made_rows_most_frequent_first():
    rows = pd.DataFrame({
        "case_id": [0, 1, 2, 3, 4, 5],
        "estimator": ["plug"] * 5 + ["dimes"],
        "status": ["failed", "failed", "failed", "failed", "ok", "failed"],
        "reason": ["implausible", "estimator_failed", "implausible", "estimator_failed", "ok", "case_failed"],
        "error": ["estimator plug: implausible: field 'velocity_east_mps' must be finite when valid; got nan",
                  'estimator plug: crashed: RuntimeError: boom | File "/p/plug.py", line 9, in estimate',
                  "estimator plug: implausible: speed 1e9 m/s",
                  "estimator plug: exit status 3: cannot lock", "", 'MemoryError: out | File "/x.py", line 2, in f'],
    })
    summaries = {summary.estimator: summary for summary in failure_summary(rows)}
    plug = summaries["plug"]
    assert (plug.rows, plug.failed) == (5, 4)
    assert [(kind.kind, kind.rows, kind.example_where) for kind in plug.kinds] == [
        ("implausible answer", 2, "case 0"), ("crashed (RuntimeError)", 1, "case 1"), ("exit status 3", 1, "case 3")]
    assert [kind.kind for kind in summaries["dimes"].kinds] == ["case failed (MemoryError)"]
    assert failure_kind("estimator_failed", "estimator plug: field 'valid' must be true or false") == "contract violation"


def test_a_long_error_is_abbreviated_in_the_middle_never_in_its_file_and_line():
    where = 'File "/very/long/' + "deep/" * 40 + 'plug.py", line 1234, in estimate'
    text = "estimator plug: crashed: RuntimeError: " + "word " * 200 + "END | " + where
    short = abbreviate_error(text, limit=120)
    assert short.endswith(" | " + where)
    message = short[:-len(" | " + where)]
    assert len(message) == 120 and "..." in message and message.startswith("estimator plug: crashed") and message.endswith("END")
    assert abbreviate_error("a\nb  c") == "a b c" and abbreviate_error(None) == "no error text"


def test_markdown_cells_escape_what_they_quote():
    cell = markdown_cell("a | b `c`\nnext <tag> __init__.py *x*")
    assert unescaped_pipes(cell) == 0 and "\n" not in cell
    assert cell == "a \\| b \\`c\\`<br>next &lt;tag&gt; \\_\\_init\\_\\_.py \\*x\\*"
    assert markdown_cell(float("nan")) == "" and markdown_cell("gcp_1", emphasis=False) == "gcp_1"


def test_a_markdown_grid_escapes_a_quoted_name_holding_a_pipe_a_backtick_or_a_newline():
    from campaign.report.aggregate import render_grid

    text = render_grid(["Class", "Cases"], [["gcp|rough `v2`\nnew", "3"], ["plain", "4"]], markdown=True)
    lines = text.splitlines()
    assert len(lines) == 4 and all(unescaped_pipes(line) == 3 for line in lines[2:]), text
    assert lines[2] == "| gcp\\|rough \\`v2\\`<br>new | 3 |"


def test_a_sweeps_failure_example_names_its_point_and_the_report_lines_count_every_kind():
    from campaign.report.failures import failure_report_lines

    rows = pd.DataFrame({"point_id": [2, 2, 5], "case_id": [7, 8, 7], "estimator": ["plug"] * 3,
                         "status": ["failed"] * 3, "reason": ["implausible", "estimator_failed", "implausible"],
                         "error": ["estimator plug: implausible: nan", "estimator plug: timeout: no result within 5 s",
                                   "estimator plug: implausible: inf"]})
    lines = failure_report_lines(failure_summary(rows))
    assert lines[0].startswith("estimator plug: 3 of 3 rows failed, 2 kinds")
    assert lines[1:] == ["  2 x implausible answer, e.g. point 2 case 7: estimator plug: implausible: nan",
                         "  1 x timeout, e.g. point 2 case 8: estimator plug: timeout: no result within 5 s"]
