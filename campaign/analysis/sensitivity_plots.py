"""The sensitivity figures of ``campaign sensitivity``: per estimator, ranked bars of the indices with their
intervals (one panel per output), and each output against its two most influential inputs (the second the
best-ranked one that is not a near copy of the first)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from campaign.analysis.case_inputs import OUTPUT_MEANINGS  # noqa: E402

TITLE_POINTS = 12
LABEL_POINTS = 10


def ranked_bars(table: pd.DataFrame, estimator: str, path: Path, top: int = 12) -> Path:
    """Horizontal bars of the ``top`` indices per output of ``estimator``, bootstrap intervals as error bars,
    inputs indistinguishable from noise drawn grey."""
    rows = table[table["estimator"] == estimator]
    outputs = list(dict.fromkeys(rows["output"]))
    figure, axes_list = plt.subplots(1, len(outputs), figsize=(8.5 * len(outputs), 0.42 * top + 1.8), squeeze=False)
    for axes, output in zip(axes_list[0], outputs):
        shown = rows[rows["output"] == output].head(top).iloc[::-1]
        positions = np.arange(len(shown))
        colours = ["0.7" if noise else "tab:blue" for noise in shown["noise"]]
        errors = np.vstack([shown["index"] - shown["low"], shown["high"] - shown["index"]]).clip(min=0)
        axes.barh(positions, shown["index"], xerr=errors, color=colours, capsize=3)
        axes.set_yticks(positions, shown["input"], fontsize=LABEL_POINTS - 1)
        axes.set_xlim(0, 1)
        axes.set_xlabel("PAWN index (expected KS distance, 0-1)", fontsize=LABEL_POINTS)
        cases = int(shown["cases"].iloc[0]) if len(shown) else 0
        axes.set_title(f"{estimator}: {output}\n{OUTPUT_MEANINGS[output]}, {cases} cases",
                       fontsize=TITLE_POINTS)
    figure.text(0.01, 0.005, "grey: indistinguishable from noise (Holm, 5 %); bars: 95 % bootstrap interval",
                fontsize=LABEL_POINTS - 1)
    figure.tight_layout(rect=(0, 0.03, 1, 1))
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def top_two(table: pd.DataFrame, inputs: pd.DataFrame, outputs: pd.DataFrame, estimator: str, path: Path) -> Path:
    """Each analysed output of ``estimator`` against its two highest-ranked inputs: the cases as points at
    (first input, second input), coloured by the output."""
    rows = table[table["estimator"] == estimator]
    analysed = list(dict.fromkeys(rows["output"]))
    figure, axes_list = plt.subplots(1, len(analysed), figsize=(6.0 * len(analysed), 5.0), squeeze=False)
    for axes, output in zip(axes_list[0], analysed):
        ranked = rows[rows["output"] == output]["input"].tolist()
        first, second = ranked[0], _second_input(inputs, ranked)
        values = outputs[output]
        defined = values.notna()
        horizontal, horizontal_ticks = _axis_values(inputs.loc[defined, first])
        vertical, vertical_ticks = _axis_values(inputs.loc[defined, second])
        points = axes.scatter(horizontal, vertical, c=values[defined], s=14, cmap="viridis")
        if horizontal_ticks:
            axes.set_xticks(range(len(horizontal_ticks)), horizontal_ticks)
        if vertical_ticks:
            axes.set_yticks(range(len(vertical_ticks)), vertical_ticks)
        axes.set_xlabel(first, fontsize=LABEL_POINTS)
        axes.set_ylabel(second, fontsize=LABEL_POINTS)
        axes.set_title(f"{estimator}: {output} against its top two inputs", fontsize=TITLE_POINTS)
        bar = figure.colorbar(points, ax=axes)
        bar.set_label(OUTPUT_MEANINGS[output], fontsize=LABEL_POINTS)
        if set(np.unique(values[defined])) <= {0.0, 1.0}:
            bar.set_ticks([0.0, 1.0], labels=["no (0)", "yes (1)"])
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def _second_input(inputs: pd.DataFrame, ranked: list[str], redundant: float = 0.8) -> str:
    """The highest-ranked input after the first that is not a near copy of it (|Spearman correlation| below
    ``redundant``: the total attitude error of image 2 says nothing the one of image 1 did not), else the
    second-ranked one."""
    first = inputs[ranked[0]]
    for name in ranked[1:]:
        candidate = inputs[name]
        if first.dtype.kind not in "fiub" or candidate.dtype.kind not in "fiub":
            return name
        correlation = first.corr(candidate, method="spearman")
        if not np.isfinite(correlation) or abs(correlation) < redundant:
            return name
    return ranked[1] if len(ranked) > 1 else ranked[0]


def _axis_values(values: pd.Series) -> tuple[np.ndarray, list[str]]:
    """Numbers to plot for an input, and tick labels when it is categorical text (class names)."""
    if values.dtype.kind in "fiub":
        return values.to_numpy(dtype=float), []
    categories = sorted(values.unique())
    codes = values.map({name: code for code, name in enumerate(categories)}).to_numpy(dtype=float)
    jitter = np.random.default_rng(0).uniform(-0.2, 0.2, codes.size)     # cases of one class side by side
    return codes + jitter, categories
