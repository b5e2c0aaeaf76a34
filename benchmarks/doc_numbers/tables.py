"""The tables the pages quote, generated from the record: the campaigns as shipped beside the paper
(``table sites``), the fidelity presets (``table fidelity_presets``, ``table fidelity_presets_detail``), the
speed-up work (``table speedup``), and a recorded table as printed (``table NAME`` of ``tables.csv``).

Each is a caption stating the date it was measured, a blank line, then the Markdown table.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable

from benchmarks.doc_numbers.record import SITE_TABLES_FILE, Fact, RecordedTable, RecordError, Sources, compact_number


def markdown_table(header: list[str], body: list[list[str]]) -> str:
    """The Markdown table of ``header`` and the rows ``body`` (one line per row, an empty cell as one space)."""
    def line(cells: list[str]) -> str:
        return "|" + "|".join(f" {cell} " if cell else " " for cell in cells) + "|"

    return "\n".join([line(header), "|" + "---|" * len(header)] + [line(cells) for cells in body])


def recorded_table(table: RecordedTable) -> str:
    """A recorded table: caption with the date, source and conditions, a blank line, then the Markdown table."""
    notes = "; ".join(note for note in (table.source, table.conditions) if note)
    return f"Measured {table.date} ({notes}):\n\n" + markdown_table(table.header, table.rows)


def _one_date(facts: list[Fact], table: str) -> str:
    dates = sorted({fact.date for fact in facts})
    if len(dates) != 1:
        raise RecordError(f"table {table}: its facts were measured on different days ({', '.join(dates)}); "
                          "import them from one run")
    return dates[0]


def sites_table(sources: Sources) -> str:
    """The campaigns as shipped, per class and site, beside the paper's Tables 1 and 2 (``table sites``).

    From ``site_tables.csv`` (the first estimator of each store, as ``campaign-table`` wrote it) and
    ``paper_tables.csv``; a caption line with the stores' settings and date, then the table.
    """
    rows = sources.site_rows
    if not rows:
        raise RecordError(f"{SITE_TABLES_FILE} has no rows; run campaign-table on finished stores")
    paper = {(row["site"], row["row"]): row for row in sources.paper_rows}
    dates = sorted({row["date"] for row in rows})
    settings = sorted({(row["seed"], row["cases_scale"], row["fidelity"], row["flat_field"], row["estimator"],
                        row["false_valid_mps"]) for row in rows})
    if len(settings) != 1:
        raise RecordError(f"{SITE_TABLES_FILE}: the stores differ in seed, cases scale, fidelity, flat field, "
                          f"estimator or false-valid threshold: {settings}")
    seed, cases_scale, fidelity, flat_field, estimator, false_valid_mps = settings[0]
    scale = "all cases" if float(cases_scale) == 1.0 else f"cases_scale {cases_scale}"
    sites = " and ".join(dict.fromkeys(row["site"] for row in rows))
    caption = (f"The {sites} campaigns as shipped (seed {seed}, {scale}, {fidelity} fidelity, {flat_field} flat "
               f"field, estimator `{estimator}`), next to the paper's Tables 1 and 2; false-valid = valid with a "
               f"velocity error above {compact_number(float(false_valid_mps))} m/s; measured {' and '.join(dates)}:")
    header = ["class", "cases", "paper % valid", "paper error (m/s, mean+3σ)", "% valid (valid/ran)",
              "false-valid", "error, magnitude (m/s, mean+3σ)", "error, per axis", "attitude floor, magnitude / per axis"]
    body = []
    for row in rows:
        quoted = paper.get((row["site"], row["row"]), {})
        name = f"{row['site']} (weighted)" if row["row"] == "site" else row["row"]
        ran = int(row["cases"]) - int(row["failed"])
        body.append([name, row["cases"],
                     f"{quoted['pct_valid']} %" if quoted else "",
                     quoted.get("error_mean_3sigma_mps", ""),
                     f"{float(row['pct_valid']):.1f}% ({row['valid']}/{ran})",
                     row["false_valid"], f"{float(row['error_mean_3sigma_mps']):.2f}",
                     _two_decimals(row["error_axis_mean_3sigma_mps"]),
                     f"{_two_decimals(row['floor_mean_3sigma_mps'])} / {_two_decimals(row['floor_axis_mean_3sigma_mps'])}"])
    return caption + "\n\n" + markdown_table(header, body)


def _two_decimals(text: str) -> str:
    """A recorded statistic as printed in the site table (blank when the store had none)."""
    return f"{float(text):.2f}" if text else "n/a"


FIDELITY_PRESETS = ("reference", "high", "default", "fast")


def _fidelity_facts(sources: Sources, preset: str, columns: Iterable[str]) -> dict[str, Fact]:
    return {column: sources.fact(f"bench/fidelity/{preset}/{column}") for column in columns}


def _image_ms(facts: dict[str, Fact], preset: str) -> str:
    if preset == "reference":
        return facts["ms_per_image"].value
    return f"{facts['ms_per_image'].value} ({facts['scene_ms'].value} + {facts['camera_ms'].value})"


def fidelity_table(sources: Sources, detail: bool) -> str:
    """The fidelity presets' time against error, from the ``bench/fidelity/<preset>/...`` facts.

    ``detail``: also the worst image, the largest pixel error and the velocity change against ``reference``
    (``table fidelity_presets_detail``); else the mean RMS error and the largest velocity change only
    (``table fidelity_presets``).
    """
    columns = ["ms_per_image", "scene_ms", "camera_ms", "ms_per_case", "rms_dn_vs_reference_mean",
               "dv_vs_reference_max_mps"]
    if detail:
        columns += ["rms_dn_vs_reference_max", "max_dn_vs_reference", "dv_vs_reference_mean_mps"]
    per_preset = {preset: _fidelity_facts(sources, preset,
                                          ["ms_per_image", "ms_per_case"] if preset == "reference" else columns)
                  for preset in FIDELITY_PRESETS}
    name = "fidelity_presets_detail" if detail else "fidelity_presets"
    everything = [fact for facts in per_preset.values() for fact in facts.values()]
    date = _one_date(everything, name)
    conditions = "; ".join(dict.fromkeys(fact.conditions for fact in everything if fact.conditions))
    caption = f"Measured {date} (`python -m benchmarks fidelity`{'; ' + conditions if conditions else ''}):"
    if detail:
        header = ["preset", "ms/image (scene + camera)", "ms/case (3 images + estimator)",
                  "expected-image error vs reference, RMS mean / worst image / max pixel (DN)",
                  "velocity change vs reference, mean / max (m/s)"]
    else:
        header = ["preset", "ms/image (scene + camera)", "ms/case (3 images + estimator)",
                  "expected-image RMS error vs reference (DN, mean)", "velocity change vs reference (m/s, max)"]
    body = []
    for preset, facts in per_preset.items():
        cells = [preset, _image_ms(facts, preset), facts["ms_per_case"].value]
        if preset == "reference":
            cells += ["0", "0"]
        elif detail:
            cells += [f"{facts['rms_dn_vs_reference_mean'].value} / {facts['rms_dn_vs_reference_max'].value} / "
                      f"{facts['max_dn_vs_reference'].value}",
                      f"{facts['dv_vs_reference_mean_mps'].value} / {facts['dv_vs_reference_max_mps'].value}"]
        else:
            cells += [facts["rms_dn_vs_reference_mean"].value, facts["dv_vs_reference_max_mps"].value]
        body.append(cells)
    return caption + "\n\n" + markdown_table(header, body)


#: the speed-up table: row label -> fact key prefix (``<prefix>/before``, ``/after``, ``/ratio``)
SPEEDUP_ROWS = (
    ("case (3 images, sensors, reference estimator)", "speedup/case_cpu_ms"),
    ("camera chain per image", "speedup/camera_chain_cpu_ms"),
    ("optics PSF per image: still / block smear / moving", "speedup/optics_psf_cpu_ms"),
    ("reference estimator (same bits on 136 estimates and the 1090 adversarial triples)", "speedup/estimator_cpu_ms"),
    ("reference preset, one image", "speedup/reference_image_cpu_ms"),
    ("campaign worker: wall-time parallel efficiency (loaded machine)", "speedup/parallel_efficiency"),
)


def speedup_table(sources: Sources) -> str:
    """Before/after the speed-up work, both versions back to back in one run (``table speedup``)."""
    everything: list[Fact] = []
    body = []
    row_dates: dict[str, str] = {}
    for label, prefix in SPEEDUP_ROWS:
        before, after = sources.fact(f"{prefix}/before"), sources.fact(f"{prefix}/after")
        ratio = sources.facts.get(f"{prefix}/ratio")
        facts = [before, after] + ([ratio] if ratio else [])
        row_dates[label.split(":")[0].split(" (")[0]] = _one_date(facts, f"speedup, row {label!r}")
        everything += facts
        body.append([label, before.value, after.value, ratio.printed() if ratio else ""])
    dates = list(row_dates.values())
    date = max(set(dates), key=dates.count)
    exceptions = "; ".join(f"{label}: {day}" for label, day in row_dates.items() if day != date)
    conditions = "; ".join(dict.fromkeys(fact.conditions for fact in everything if fact.conditions))
    notes = "; ".join(note for note in (exceptions, conditions) if note)
    caption = f"Measured {date}{' (' + notes + ')' if notes else ''}:"
    return caption + "\n\n" + markdown_table(["", "before", "after", "ratio"], body)


#: generated tables by block name
TABLES: dict[str, Callable[[Sources], str]] = {
    "sites": sites_table,
    "fidelity_presets": lambda sources: fidelity_table(sources, detail=False),
    "fidelity_presets_detail": lambda sources: fidelity_table(sources, detail=True),
    "speedup": speedup_table,
}

