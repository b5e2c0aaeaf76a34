"""``campaign sensitivity DIR``: which recorded input drives each estimator's validity, false-valid answers and
velocity error, from the cases a finished campaign already holds (no new runs).

For every estimator of the store and each output of :mod:`campaign.analysis.case_inputs` the inputs are ranked
by their PAWN index (:mod:`campaign.analysis.given_data`: expected KS distance between the output's
distribution and its distribution with the input known), with a bootstrap interval and a Holm-corrected
permutation test marking the inputs whose effect is indistinguishable from noise. The result is a table
(:data:`SENSITIVITY_COLUMNS`, written as ``sensitivity.parquet`` in the store) and its printed summary.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from campaign.analysis.case_inputs import OUTPUT_MEANINGS, OUTPUTS, case_inputs, case_outputs
from campaign.analysis.given_data import analyse_input, continuous_null, holm_noise, is_categorical, slice_count
from campaign.analysis.sensitivity_plots import ranked_bars, top_two
from campaign.store.campaign_store import CampaignStore
from campaign.store.errors import StoreError
from campaign.store.stored_config import stored_config

METHOD = "pawn_mean_ks"
"""Recorded in every row's ``method``: the PAWN index as the size-weighted mean KS distance over slices."""
SENSITIVITY_COLUMNS = ["estimator", "output", "input", "index", "low", "high", "p_value", "noise", "rank",
                       "cases", "slices", "categorical", "confidence", "method"]
MIN_CASES = 20
"""Fewer cases with a defined output than this: the output is not analysed (a line says so)."""
FILE_NAME = "sensitivity.parquet"


@dataclass(frozen=True)
class AnalysisSettings:
    """How the indices' uncertainty is estimated.

    Attributes
    ----------
    resamples : int
        Bootstrap replicates of each interval.
    permutations : int
        Permutations of each null distribution (the smallest p-value is 1 / (permutations + 1)).
    confidence : float
        Level of the intervals.
    alpha : float
        Family-wise level of the noise test over one output's inputs (Holm).
    seed : int
        Seed of the resampling (same seed, same table).
    """

    resamples: int = 300
    permutations: int = 2000
    confidence: float = 0.95
    alpha: float = 0.05
    seed: int = 0


def analyse_output(inputs: pd.DataFrame, outputs: pd.Series, settings: AnalysisSettings,
                   rng: np.random.Generator) -> pd.DataFrame:
    """Every input's index for one output (rows sorted by decreasing index, ``rank`` 1 first).

    Parameters
    ----------
    inputs : pandas.DataFrame
        One column per input, one row per case (index ``case_id``).
    outputs : pandas.Series
        The output per case (same index); NaN cases are left out.
    settings : AnalysisSettings
        Resampling and test settings.
    rng : numpy.random.Generator
        Source of the resamples and permutations.

    Returns
    -------
    pandas.DataFrame
        Columns ``input, index, low, high, p_value, noise, rank, cases, slices, categorical``.
    """
    defined = outputs.notna().to_numpy()
    values = outputs.to_numpy(dtype=float)[defined]
    cases = int(values.size)
    slices = slice_count(cases)
    null = continuous_null(values, rng, settings.permutations, slices)
    rows = []
    for name in inputs.columns:
        column = inputs[name].to_numpy()[defined]
        estimate = analyse_input(column, values, rng, resamples=settings.resamples,
                                 permutations=settings.permutations, confidence=settings.confidence,
                                 slices=slices, null=None if is_categorical(column) else null)
        rows.append({"input": name, "index": estimate.index, "low": estimate.low, "high": estimate.high,
                     "p_value": estimate.p_value, "slices": estimate.slices, "categorical": estimate.categorical})
    table = pd.DataFrame(rows)
    table["noise"] = holm_noise(table["p_value"].to_numpy(), settings.alpha)
    table = table.sort_values(["index", "input"], ascending=[False, True], kind="stable").reset_index(drop=True)
    table["rank"] = np.arange(1, len(table) + 1)
    table["cases"] = cases
    return table


@dataclass(frozen=True)
class StoreCases:
    """What a store's cases give the analysis: the result rows, one input row per case
    (:func:`campaign.analysis.case_inputs.case_inputs`) and the false-valid threshold (m/s)."""

    results: pd.DataFrame
    inputs: pd.DataFrame
    false_valid_mps: float

    def outputs(self, estimator: str) -> pd.DataFrame:
        """One estimator's outputs per case, aligned with :attr:`inputs`."""
        return case_outputs(self.results, estimator, self.false_valid_mps).reindex(self.inputs.index)


def read_store_cases(directory: str | Path) -> StoreCases:
    """Read a finished campaign store once for the analysis (StoreError, one line, when it is none or empty)."""
    store = CampaignStore(directory)
    manifest = store.manifest()
    if manifest is None:
        raise StoreError(f"{directory}: not a campaign directory (no manifest.json); allowed: a campaign store "
                         "written by `campaign submit` (a sweep's points are its subdirectories)")
    results = store.results()
    if results.empty:
        raise StoreError(f"{directory}: no case results yet; run `campaign submit` first")
    config = stored_config(store, manifest)
    return StoreCases(results, case_inputs(results, config.site.trajectory_path), config.false_valid_mps)


def store_sensitivity(directory: str | Path, settings: AnalysisSettings = AnalysisSettings(),
                      estimators: list[str] | None = None,
                      cases: StoreCases | None = None) -> tuple[pd.DataFrame, list[str]]:
    """The sensitivity table of a finished campaign store and the notes on what was not analysed.

    Parameters
    ----------
    directory : str or pathlib.Path
        The campaign store.
    settings : AnalysisSettings
        Resampling and test settings.
    estimators : list of str, optional
        Only these estimators (default: every estimator of the store).
    cases : StoreCases, optional
        The store already read (:func:`read_store_cases`).

    Returns
    -------
    (pandas.DataFrame, list of str)
        Rows :data:`SENSITIVITY_COLUMNS`; notes such as "no false-valid case".
    """
    cases = cases or read_store_cases(directory)
    results, inputs = cases.results, cases.inputs
    names = sorted(results["estimator"].unique()) if estimators is None else estimators
    unknown = sorted(set(names) - set(results["estimator"].unique()))
    if unknown:
        raise StoreError(f"{directory}: no estimator {', '.join(unknown)} in the store; allowed: "
                         f"{', '.join(sorted(results['estimator'].unique()))}")
    rng = np.random.default_rng(settings.seed)
    tables, notes = [], []
    for estimator in names:
        outputs = cases.outputs(estimator)
        for output in OUTPUTS:
            series = outputs[output]
            defined = int(series.notna().sum())
            if defined < MIN_CASES:
                notes.append(f"{estimator}: {output}: {defined} cases with a value (< {MIN_CASES}): not analysed")
                continue
            if series.dropna().nunique() < 2:
                notes.append(f"{estimator}: {output}: the same value ({series.dropna().iloc[0]:g}) in all {defined} "
                             "cases: nothing to attribute")
                continue
            table = analyse_output(inputs, series, settings, rng)
            table.insert(0, "output", output)
            table.insert(0, "estimator", estimator)
            tables.append(table)
    if not tables:
        return pd.DataFrame(columns=SENSITIVITY_COLUMNS), notes
    table = pd.concat(tables, ignore_index=True)
    table["confidence"] = settings.confidence
    table["method"] = METHOD
    return table[SENSITIVITY_COLUMNS], notes


def write_sensitivity(directory: str | Path, table: pd.DataFrame, settings: AnalysisSettings) -> Path:
    """Write ``sensitivity.parquet`` in the store (its settings in the file's metadata); returns its path."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(directory) / FILE_NAME
    arrow = pa.Table.from_pandas(table, preserve_index=False)
    metadata = {b"moc2dimes.sensitivity": json.dumps(settings.__dict__, sort_keys=True).encode()}
    arrow = arrow.replace_schema_metadata({**(arrow.schema.metadata or {}), **metadata})
    temporary = path.with_suffix(".parquet.tmp")
    pq.write_table(arrow, temporary)
    temporary.replace(path)
    return path


def format_sensitivity(table: pd.DataFrame, notes: list[str], top: int = 8) -> str:
    """The ranked summary printed by ``campaign sensitivity``: per estimator and output the ``top`` inputs
    with index, interval and p-value, then the inputs indistinguishable from noise counted (fits 100 columns)."""
    lines = []
    for (estimator, output), rows in table.groupby(["estimator", "output"], sort=False):
        cases = int(rows["cases"].iloc[0])
        confidence = float(rows["confidence"].iloc[0])
        lines.append(f"{estimator}: {output} -- {OUTPUT_MEANINGS[output]}, {cases} cases "
                     f"(PAWN index, {confidence:.0%} interval)")
        lines.append(f"  {'rank':>4}  {'input':<44} {'index':>6}  {'interval':<13} {'p':>7}")
        for row in rows.head(top).itertuples():
            flag = "  noise" if row.noise else ""
            lines.append(f"  {row.rank:>4}  {row.input:<44} {row.index:6.3f}  [{row.low:.3f}-{row.high:.3f}] "
                         f"{row.p_value:7.4f}{flag}")
        influential = int((~rows["noise"]).sum())
        lines.append(f"  {influential} of {len(rows)} inputs distinguishable from noise (Holm, family-wise 5 %)"
                     + (f"; the other {len(rows) - top} are in {FILE_NAME}" if len(rows) > top else ""))
        lines.append("")
    lines.extend(f"note: {note}" for note in notes)
    return "\n".join(lines).rstrip() + "\n"


def analyse_store(directory: str | Path, settings: AnalysisSettings = AnalysisSettings(),
                  estimators: list[str] | None = None) -> str:
    """``campaign sensitivity`` on one store: compute the table, write ``sensitivity.parquet`` and the figures
    (``sensitivity_<estimator>.png``, ``sensitivity_top2_<estimator>.png``) in the store, return the printed
    summary followed by the files written."""
    directory = Path(directory)
    cases = read_store_cases(directory)
    table, notes = store_sensitivity(directory, settings, estimators, cases)
    written = [write_sensitivity(directory, table, settings)]
    for estimator in dict.fromkeys(table["estimator"]):
        written.append(ranked_bars(table, estimator, directory / f"sensitivity_{estimator}.png"))
        written.append(top_two(table, cases.inputs, cases.outputs(estimator), estimator,
                               directory / f"sensitivity_top2_{estimator}.png"))
    return format_sensitivity(table, notes) + "wrote " + ", ".join(str(path) for path in written) + "\n"
