"""The measured numbers of the README and docs/ come from one record (docs/measured/): every generated block
equals what the record generates, a block edited by hand fails the check, and the commands that feed the
record (a ``make bench`` CSV, finished campaign stores) rewrite the blocks.

The generator runs as the command the lead and CI run (``python -m benchmarks.doc_numbers``), in a
subprocess: the tests import nothing from ``benchmarks/``. Hand edits are made on a temporary copy of the
pages and the record, never on the checkout.
"""
from __future__ import annotations

import csv
import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FACTS = Path("docs/measured/facts.csv")
BLOCK = re.compile(r"<!-- measured:begin (?P<name>[^>]*?) -->(?P<body>.*?)<!-- measured:end -->", re.DOTALL)


def doc_numbers(*args: str, root: Path = REPO) -> subprocess.CompletedProcess:
    """Run ``python -m benchmarks.doc_numbers --root ROOT ARGS`` from the checkout."""
    return subprocess.run([sys.executable, "-m", "benchmarks.doc_numbers", "--root", str(root), *args],
                          cwd=REPO, capture_output=True, text=True, timeout=120)


@pytest.fixture
def copy(tmp_path: Path) -> Path:
    """A temporary root holding copies of the pages, the record and pyproject.toml."""
    root = tmp_path / "repo"
    root.mkdir()
    shutil.copy(REPO / "README.md", root / "README.md")
    shutil.copy(REPO / "pyproject.toml", root / "pyproject.toml")
    shutil.copytree(REPO / "docs", root / "docs")
    return root


def facts(root: Path) -> dict[str, dict[str, str]]:
    with (root / FACTS).open(newline="", encoding="utf-8") as handle:
        return {row["fact"]: row for row in csv.DictReader(handle)}


def blocks(text: str) -> dict[str, list[str]]:
    found: dict[str, list[str]] = {}
    for match in BLOCK.finditer(text):
        found.setdefault(match["name"].strip(), []).append(match["body"])
    return found


def test_the_checkout_pages_match_the_record():
    done = doc_numbers("check")
    assert done.returncode == 0, done.stderr


def test_the_readme_quotes_its_measured_figures_through_blocks():
    """The figures named in the issue (campaign time, test time, site table, presets) are generated blocks,
    with the values and dates of the record, and the old contradicting figures are gone."""
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    found = blocks(readme)
    record = facts(REPO)
    for key in ("bench/campaign/gusev+meridiani/wall_s", "tests/suite_wall_s"):
        assert key in found, key
        row = record[key]
        assert found[key] == [f"{row['value']} {row['unit']}"] * len(found[key])
        assert found[f"{key} date"][0] == row["date"]
    for table in ("sites", "fidelity_presets", "speedup"):
        assert f"table {table}" in found, table
        caption = found[f"table {table}"][0].strip().split("\n")[0]
        assert re.search(r"[Mm]easured \d{4}-\d{2}-\d{2}", caption), caption
    outside = BLOCK.sub("", readme)
    for stale in ("9.7 min", "41.3 s", "26.7 s"):
        assert stale not in outside
    assert "6.6 min" not in (REPO / "pyproject.toml").read_text(encoding="utf-8")


def test_a_fact_used_on_two_pages_prints_the_same_figure_on_both():
    """The campaign time and the sweep start appear in the README and docs/campaigns.md from one record row."""
    readme = blocks((REPO / "README.md").read_text(encoding="utf-8"))
    campaigns = blocks((REPO / "docs" / "campaigns.md").read_text(encoding="utf-8"))
    for key in ("bench/campaign/gusev+meridiani/wall_s", "bench/sweep/2000_points_first_batch/measured"):
        assert readme[key] and readme[key][0] == campaigns[key][0]


def test_a_copy_passes_and_a_block_edited_by_hand_fails(copy: Path):
    assert doc_numbers("check", root=copy).returncode == 0
    readme = copy / "README.md"
    text = readme.read_text(encoding="utf-8")
    wall = facts(copy)["bench/campaign/gusev+meridiani/wall_s"]
    block = (f"<!-- measured:begin bench/campaign/gusev+meridiani/wall_s -->{wall['value']} {wall['unit']}"
             "<!-- measured:end -->")
    assert block in text
    readme.write_text(text.replace(block, block.replace(f">{wall['value']} ", ">99.9 "), 1), encoding="utf-8")
    done = doc_numbers("check", root=copy)
    assert done.returncode == 1
    assert "README.md" in done.stderr and "bench/campaign/gusev+meridiani/wall_s" in done.stderr
    # write puts the record's figure back, and the copy passes again
    assert doc_numbers("write", root=copy).returncode == 0
    assert readme.read_text(encoding="utf-8") == text
    assert doc_numbers("check", root=copy).returncode == 0


def test_a_hand_edited_table_cell_fails(copy: Path):
    readme = copy / "README.md"
    text = readme.read_text(encoding="utf-8")
    assert "| gcp | 186 |" in text
    readme.write_text(text.replace("| gcp | 186 |", "| gcp | 187 |", 1), encoding="utf-8")
    done = doc_numbers("check", root=copy)
    assert done.returncode == 1 and "table sites" in done.stderr


def test_a_fact_recorded_twice_fails(copy: Path):
    path = copy / FACTS
    lines = path.read_text(encoding="utf-8").splitlines()
    row = next(line for line in lines if line.startswith("tests/suite_wall_s,"))
    path.write_text("\n".join(lines + [row.replace(",700,", ",580,")]) + "\n", encoding="utf-8")
    done = doc_numbers("check", root=copy)
    assert done.returncode == 1 and "recorded twice" in done.stderr and "tests/suite_wall_s" in done.stderr


def test_a_superseded_figure_outside_a_block_fails(copy: Path):
    superseded = facts(copy)["tests/suite_wall_s"]["superseded"].split(";")[0].strip()
    assert superseded
    page = copy / "docs" / "campaigns.md"
    page.write_text(page.read_text(encoding="utf-8") + f"\nThe suite takes {superseded}.\n", encoding="utf-8")
    done = doc_numbers("check", root=copy)
    assert done.returncode == 1 and superseded in done.stderr and "docs/campaigns.md" in done.stderr
    # also in pyproject.toml, which has no blocks
    page.write_text(page.read_text(encoding="utf-8").replace(f"\nThe suite takes {superseded}.\n", ""),
                    encoding="utf-8")
    assert doc_numbers("check", root=copy).returncode == 0
    pyproject = copy / "pyproject.toml"
    pyproject.write_text(pyproject.read_text(encoding="utf-8") + f"# the suite: {superseded}\n", encoding="utf-8")
    done = doc_numbers("check", root=copy)
    assert done.returncode == 1 and "pyproject.toml" in done.stderr


def test_an_unknown_fact_and_an_unpaired_marker_fail(copy: Path):
    page = copy / "docs" / "sitedata.md"
    original = page.read_text(encoding="utf-8")
    page.write_text(original + "\n<!-- measured:begin no/such/fact -->1 s<!-- measured:end -->\n", encoding="utf-8")
    done = doc_numbers("check", root=copy)
    assert done.returncode == 1 and "no/such/fact" in done.stderr
    page.write_text(original + "\n<!-- measured:begin tests/suite_wall_s -->700 s\n", encoding="utf-8")
    done = doc_numbers("check", root=copy)
    assert done.returncode == 1 and "without its pair" in done.stderr


def test_import_bench_updates_the_facts_and_their_blocks(copy: Path):
    """A make bench CSV (as benchmarks/__main__.py writes it: a benchmark column, per-case rows without a
    name) updates the bench/ facts it holds, dated by its stamp, rounded to three significant figures."""
    bench = copy / "bench-20261130T010203.csv"
    with bench.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=["benchmark", "name", "site", "case_id", "t_case_ms", "cases",
                                                    "wall_s", "ms_per_case_median", "measured", "target", "unit",
                                                    "ratio", "meets"])
        writer.writeheader()
        writer.writerow({"benchmark": "campaign", "site": "gusev", "case_id": 7, "t_case_ms": 12.5})
        writer.writerow({"benchmark": "campaign", "name": "campaign/gusev+meridiani", "cases": 630,
                         "wall_s": 123.456, "ms_per_case_median": 251.04, "measured": 123.456, "target": 30.0,
                         "unit": "s", "ratio": 4.1, "meets": False})
    before = facts(copy)
    done = doc_numbers("import-bench", str(bench), "--conditions", "test machine", root=copy)
    assert done.returncode == 0, done.stderr
    after = facts(copy)
    wall = after["bench/campaign/gusev+meridiani/wall_s"]
    assert (wall["value"], wall["unit"], wall["date"]) == ("123", "s", "2026-11-30")
    assert after["bench/campaign/gusev+meridiani/ms_per_case_median"]["value"] == "251"
    assert "bench-20261130T010203.csv" in wall["source"] and wall["conditions"] == "test machine"
    assert wall["superseded"] == before["bench/campaign/gusev+meridiani/wall_s"]["superseded"]
    # facts the CSV does not hold are kept as they were; no new facts without --add
    assert after["tests/suite_wall_s"] == before["tests/suite_wall_s"]
    assert set(after) == set(before)
    readme = (copy / "README.md").read_text(encoding="utf-8")
    assert "<!-- measured:begin bench/campaign/gusev+meridiani/wall_s -->123 s<!-- measured:end -->" in readme
    assert "<!-- measured:begin bench/campaign/gusev+meridiani/wall_s date -->2026-11-30<!-- measured:end -->" in readme
    campaigns = (copy / "docs" / "campaigns.md").read_text(encoding="utf-8")
    assert "<!-- measured:begin bench/campaign/gusev+meridiani/wall_s -->123 s<!-- measured:end -->" in campaigns
    assert doc_numbers("check", root=copy).returncode == 0
    # --add records the other numeric columns of named rows (not the target's own columns)
    assert doc_numbers("import-bench", str(bench), "--add", root=copy).returncode == 0
    added = facts(copy)
    assert added["bench/campaign/gusev+meridiani/cases"]["value"] == "630"
    assert "bench/campaign/gusev+meridiani/target" not in added
    assert not any(key.startswith("bench//") for key in added)


def _store(root: Path, site: str, created: str, rows: list[tuple], statistics: bool = False) -> Path:
    """A finished store as campaign-table reads it: manifest.json and table.csv (as campaign table writes; with
    ``statistics`` the per-axis error and attitude-floor columns too, else as a store tabulated before them)."""
    store = root / site.lower()
    store.mkdir()
    manifest = {"site": site, "created": created, "seed": 3, "estimators": ["dimes", "other"],
                "config": {"campaign": {"cases_scale": 0.5, "false_valid_mps": 5.0},
                           "estimator": {"flat_field": "calibrated"}, "scene": {"fidelity": "fast"}}}
    (store / "manifest.json").write_text(json.dumps(manifest), encoding="utf-8")
    with (store / "table.csv").open("w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["estimator", "class", "cases", "valid", "failed", "pct_valid", "false_valid",
                         "worst_valid_error_mps", "error_mean_3sigma_mps", "ellipse_fraction", "weighted_pct_valid",
                         "weighted_error_mps"] + (["error_axis_mean_3sigma_mps", "floor_mean_3sigma_mps",
                                                   "floor_axis_mean_3sigma_mps"] if statistics else []))
        for row in rows:
            writer.writerow(row)
    return store


def test_campaign_table_regenerates_the_site_table_from_stores(copy: Path):
    gusev = _store(copy, "Gusev", "2026-12-01T10:00:00+0000", [     # with the per-axis and floor statistics
        ("dimes", "gcp", 10, 9, 0, 90.0, 1, 6.0, 2.5, 0.6, 54.0, 1.5, 2.25, 2.125, 1.875),
        ("other", "gcp", 10, 2, 0, 20.0, 0, 1.0, 1.0, 0.6, 12.0, 0.6, 1.0, 1.0, 1.0),
        ("dimes", "gdcp", 8, 6, 1, 85.71428571, 0, 3.0, 3.25, 0.4, 34.28571, 1.3, 3.0, 2.5, 2.0),
        ("dimes", "Gusev", 18, 15, 1, "", 1, 6.0, "", 1.0, 88.285714, 2.8, 2.55, 2.275, 1.925),
    ], statistics=True)
    meridiani = _store(copy, "Meridiani", "2026-12-02T01:00:00+0000", [
        ("dimes", "heb", 4, 4, 0, 100.0, 0, 2.0, 1.999, 1.0, 100.0, 1.999),
        ("dimes", "Meridiani", 4, 4, 0, "", 0, 2.0, "", 1.0, 100.0, 1.999),
    ])
    done = doc_numbers("campaign-table", str(gusev), str(meridiani), root=copy)
    assert done.returncode == 0, done.stderr
    readme = (copy / "README.md").read_text(encoding="utf-8")
    table = blocks(readme)["table sites"][0]
    # the first estimator of each store; % valid of the ran cases; the site rows ellipse-weighted; the paper beside
    # beside |v|: the per-axis statistic and the attitude floor's two (n/a for a store tabulated without them)
    assert "| gcp | 10 | 98 % | 3.90 | 90.0% (9/10) | 1 | 2.50 | 2.25 | 2.12 / 1.88 |" in table
    assert "| gdcp | 8 | 100 % | 3.48 | 85.7% (6/7) | 0 | 3.25 | 3.00 | 2.50 / 2.00 |" in table
    assert "| Gusev (weighted) | 18 | 99 % | 3.73 | 88.3% (15/17) | 1 | 2.80 | 2.55 | 2.27 / 1.93 |" in table
    assert "| heb | 4 | 100 % | 3.03 | 100.0% (4/4) | 0 | 2.00 | n/a | n/a / n/a |" in table
    assert "| Meridiani (weighted) | 4 | 71 % | 3.74 | 100.0% (4/4) | 0 | 2.00 | n/a | n/a / n/a |" in table
    assert "20.0%" not in table and "| gkep |" not in table
    assert "seed 3, cases_scale 0.5, fast fidelity, calibrated flat field" in table
    assert "measured 2026-12-01 and 2026-12-02" in table
    assert blocks(readme)["table sites date"] == ["2026-12-01 and 2026-12-02"]
    assert doc_numbers("check", root=copy).returncode == 0


def test_campaign_table_refuses_a_directory_that_is_no_store(copy: Path, tmp_path: Path):
    before = (copy / "docs" / "measured" / "site_tables.csv").read_text(encoding="utf-8")
    done = doc_numbers("campaign-table", str(tmp_path / "nothing"), root=copy)
    assert done.returncode == 2 and "not a campaign store" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    assert (copy / "docs" / "measured" / "site_tables.csv").read_text(encoding="utf-8") == before


def test_a_recorded_table_is_printed_from_its_csv_and_a_hand_edit_fails(copy: Path):
    """Measured tables kept as printed (tables.csv + tables/NAME.csv): the block holds the CSV's cells under a
    caption with the recorded date; editing a cell on the page fails, editing the CSV and writing moves it."""
    readme = copy / "README.md"
    table = blocks(readme.read_text(encoding="utf-8"))["table moving_shadows"][0]
    with (copy / "docs" / "measured" / "tables" / "moving_shadows.csv").open(newline="", encoding="utf-8") as handle:
        cells = list(csv.reader(handle))
    with (copy / "docs" / "measured" / "tables.csv").open(newline="", encoding="utf-8") as handle:
        date = next(row["date"] for row in csv.DictReader(handle) if row["name"] == "moving_shadows")
    assert table.strip().split("\n")[0].startswith(f"Measured {date} (")
    assert "| " + " | ".join(cells[1]) + " |" in table
    text = readme.read_text(encoding="utf-8")
    cell = f"| {cells[4][2]} |"                 # a cell of the recorded table, edited on the page by hand
    assert cell in text
    readme.write_text(text.replace(cell, f"| {cells[4][2]}0 |", 1), encoding="utf-8")
    done = doc_numbers("check", root=copy)
    assert done.returncode == 1 and "table moving_shadows" in done.stderr
    readme.write_text(text, encoding="utf-8")
    # a row with a missing cell is refused
    path = copy / "docs" / "measured" / "tables" / "moving_shadows.csv"
    original = path.read_text(encoding="utf-8")
    path.write_text(original + "5,10\n", encoding="utf-8")
    done = doc_numbers("check", root=copy)
    assert done.returncode == 1 and "as many cells as the header" in done.stderr


def test_import_bench_records_a_range_over_the_rows_a_fact_names(copy: Path):
    """``bench/<name>|<name>|<pattern*>/<column>`` facts hold min-max over the rows they name; rows of other
    names (the x60 rate, the dust point) stay out of the 'every other effect' range."""
    ratios = {"offnominal/angular_rate_x60": 1.9, "offnominal/dust_100": 1.25, "offnominal/hot_pixels_1pct": 0.951,
              "offnominal/particle_hits_1e4": 1.1, "offnominal/heat_shield_glint": 1.02,
              "offnominal/no_blooming": 0.99, "offnominal/dark_current_x100": 1.0,
              "offnominal/nightly/dust=0,rate=1": 1.0, "offnominal/nightly/dust=100,rate=60": 2.05}
    bench = copy / "bench-20261201T000000.csv"
    with bench.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=["benchmark", "name", "case_ms", "ratio_vs_nominal"])
        writer.writeheader()
        for name, ratio in ratios.items():
            writer.writerow({"benchmark": "offnominal", "name": name, "case_ms": 100 * ratio, "ratio_vs_nominal": ratio})
    assert doc_numbers("import-bench", str(bench), root=copy).returncode == 0
    after = facts(copy)
    others = next(key for key in after if key.startswith("bench/offnominal/hot_pixels_1pct|"))
    assert after[others]["value"] == "0.951-1.10" and after[others]["date"] == "2026-12-01"
    assert after["bench/offnominal/nightly/*/ratio_vs_nominal"]["value"] == "1.00-2.05"
    assert after["bench/offnominal/angular_rate_x60/ratio_vs_nominal"]["value"] == "1.90"
    readme = (copy / "README.md").read_text(encoding="utf-8")
    assert "-->1.00-2.05<!-- measured:end --> (targets 1.3x" in readme


def test_a_superseded_figure_fails_on_a_page_without_blocks_too(copy: Path):
    """One figure per fact on every page: an old figure is refused also where a page has no block at all."""
    superseded = facts(copy)["bench/campaign/gusev+meridiani/wall_s"]["superseded"].split(";")[0].strip()
    page = copy / "docs" / "no_blocks.md"
    page.write_text(f"# A page without blocks\n\nThe Gusev campaign takes {superseded}.\n", encoding="utf-8")
    done = doc_numbers("check", root=copy)
    assert done.returncode == 1 and "docs/no_blocks.md" in done.stderr and superseded in done.stderr


def test_a_was_block_quotes_history_only_for_a_recorded_superseded_figure(copy: Path):
    row = facts(copy)["tests/suite_wall_s"]
    old = row["superseded"].split(";")[0].strip()
    page = copy / "docs" / "no_blocks.md"
    page.write_text(f"Once <!-- measured:begin tests/suite_wall_s was {old} --><!-- measured:end -->.\n",
                    encoding="utf-8")
    assert doc_numbers("write", root=copy).returncode == 0
    assert f"was {old} -->{old}<!-- measured:end -->" in page.read_text(encoding="utf-8")
    assert doc_numbers("check", root=copy).returncode == 0
    page.write_text("Once <!-- measured:begin tests/suite_wall_s was 1 min --><!-- measured:end -->.\n",
                    encoding="utf-8")
    done = doc_numbers("check", root=copy)
    assert done.returncode == 1 and "'1 min' is not a superseded figure of tests/suite_wall_s" in done.stderr


def test_the_campaign_time_has_one_figure_on_every_page():
    """The Gusev campaign time was 41.3 s, 30.3 s or 115 s depending on the page (issue 32): outside the
    generated blocks no page quotes a recorded old figure of it, and every block prints the record's."""
    record = facts(REPO)["bench/campaign/gusev+meridiani/wall_s"]
    old = [figure.strip() for figure in record["superseded"].split(";")]
    assert {"41.3 s", "30.3 s"} <= set(old)
    for page in [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]:
        text = page.read_text(encoding="utf-8")
        outside = BLOCK.sub("", text)
        for figure in old:
            assert not re.search(rf"(?<![\w.]){re.escape(figure)}(?!\w)", outside), (page.name, figure)
        for body in blocks(text).get("bench/campaign/gusev+meridiani/wall_s", []):
            assert body == f"{record['value']} {record['unit']}", page.name


def test_the_readme_has_a_dated_quick_look_and_states_what_make_test_costs():
    """Before "What a campaign gives you": the quick-look command with its measured time and date (a fact of
    the record, measured 2026-11-27 or later), and make test's time (a block) and its root/SLURM step."""
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    top = readme.split("## What a campaign gives you")[0]
    assert "campaign submit sitedata/gusev.toml --cases-scale 0.1" in top
    found = blocks(top)
    quick = facts(REPO)["campaign/quick_look_gusev_s01/wall_s"]
    assert found["campaign/quick_look_gusev_s01/wall_s"] == [f"{quick['value']} {quick['unit']}"]
    assert found["campaign/quick_look_gusev_s01/wall_s date"] == [quick["date"]] and quick["date"] >= "2026-11-27"
    assert "--cases-scale 0.1" in quick["source"] and quick["conditions"]
    assert found["tests/suite_wall_s"] and found["tests/suite_wall_s date"]
    make_test = BLOCK.sub("", top.split("**`make test` takes time and root.**")[1])
    for needed in ("root", "apt-get install", "slurmctld", "tests/slurm_node.py", "skipped"):
        assert needed in make_test, needed


def test_docs_campaigns_lists_every_command_the_readme_lists():
    """docs/campaigns.md's command list names every `campaign` command of the README's (check-estimators and
    cluster were missing)."""
    def commands(text: str, heading: str) -> set[str]:
        block = text.split(heading, 1)[1].split("```", 2)[1]
        named = set()
        for line in block.splitlines():
            line = line.split("#", 1)[0]
            if line.startswith("campaign "):
                named |= {part.split()[0] for part in line[len("campaign "):].split("|") if part.strip()}
        return named

    readme = commands((REPO / "README.md").read_text(encoding="utf-8"), "### Commands")
    campaigns = commands((REPO / "docs" / "campaigns.md").read_text(encoding="utf-8"), "## Commands")
    assert {"check-estimators", "cluster", "submit", "status"} <= readme
    assert readme <= campaigns, sorted(readme - campaigns)
