"""PNG figures: process measures over qualified failures, paired P0 - P1 differences, dSR heatmap, outcome bars.

Figures are drawn on ``matplotlib.figure.Figure`` objects with the Agg canvas, never through
pyplot, so reporting does not change the backend or state of the caller's matplotlib. An empty
subset draws an "n/a (n=0)" note in its place. Metrics are titled and scaled as registered: their
label, and percentages where the unit is "%" (else the values as measured, unit in the title).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from conflictbench.core import FAMILIES, LEVELS, PROMPT_CONDITIONS, MetricSpec
from conflictbench.metrics import qualified_failure_mask, with_model

PROMPT_COLOURS = {"p0": "#4C72B0", "p1": "#DD8452"}
DPI = 150


def _save(fig: Figure, path: Path) -> Path:
    FigureCanvasAgg(fig)
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    return path


def _empty(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, fontsize=10, color="0.35")
    ax.set_xticks([])
    ax.set_yticks([])


def _scale(metric: MetricSpec) -> tuple[float, str]:
    """(factor, unit text) the values are drawn in: percent for a "%" metric, else as measured."""
    return (100.0, "%") if metric.percent else (1.0, metric.unit)


def _titled(text: str, unit: str) -> str:
    return f"{text} ({unit})" if unit else text


def qualified_failure_distributions(frame: pd.DataFrame, path: Path, metrics: Sequence[MetricSpec]) -> Path:
    """Box plots of each metric over D_QF, one box per model (and prompt condition, side by side)."""
    frame = with_model(frame)
    qf = frame[qualified_failure_mask(frame)] if len(frame) else frame
    models = sorted(frame["model"].unique()) if len(frame) else []
    prompts = [p for p in PROMPT_CONDITIONS if len(frame) and (frame["prompt"] == p).any()] or ["p0"]
    width = 0.8 / len(prompts)
    fig = Figure(figsize=(3.2 * len(metrics), 2.6 + 0.25 * max(len(models), 1)), layout="constrained")
    axes = fig.subplots(1, len(metrics), squeeze=False)[0]
    for ax, metric in zip(axes, metrics):
        factor, unit = _scale(metric)
        ax.set_title(_titled(f"{metric.label} over D_QF", unit), fontsize=10)
        if not models:
            _empty(ax, "n/a (n=0)")
            continue
        drawn = False
        label_at = ax.get_yaxis_transform()  # x in axes fractions, y in data: notes stay inside the panel
        for pi, prompt in enumerate(prompts):
            for mi, model in enumerate(models):
                values = qf.loc[(qf["model"] == model) & (qf["prompt"] == prompt), metric.name].astype(float)
                values = factor * values[values.notna()].to_numpy()
                pos = mi + (pi - (len(prompts) - 1) / 2) * width
                if len(values) == 0:
                    ax.text(0.02, pos, "n/a (n=0)", va="center", fontsize=7, color="0.4", transform=label_at)
                    continue
                box = ax.boxplot(
                    [values],
                    positions=[pos],
                    widths=width * 0.85,
                    orientation="horizontal",
                    patch_artist=True,
                    showfliers=True,
                    flierprops={"markersize": 2, "alpha": 0.5},
                    medianprops={"color": "black"},
                )
                box["boxes"][0].set_facecolor(PROMPT_COLOURS.get(prompt, "0.7"))
                box["boxes"][0].set_alpha(0.8)
                ax.text(
                    0.99, pos, f"n={len(values)}", va="center", ha="right", fontsize=6, color="0.3", transform=label_at
                )
                drawn = True
        ax.set_yticks(range(len(models)), models, fontsize=8)
        if metric.percent:
            ax.set_xlim(-2, 120)  # room on the right for the counts
        else:
            low, high = ax.get_xlim()
            ax.set_xlim(low, high + 0.2 * (high - low))
        ax.set_ylim(len(models) - 0.5, -0.5)
        ax.grid(axis="x", alpha=0.3)
        if not drawn:
            ax.text(
                0.5, -0.45, "no qualified failures", ha="center", va="top", fontsize=8, color="0.4", transform=label_at
            )
    if len(prompts) > 1:
        handles = [_patch(PROMPT_COLOURS[p], p.upper()) for p in prompts]
        fig.legend(handles=handles, loc="outside lower center", ncol=len(prompts), fontsize=8, frameon=False)
    return _save(fig, path)


def _patch(colour: str, label: str):
    from matplotlib.patches import Patch

    return Patch(facecolor=colour, label=label, alpha=0.8)


def prompt_difference_figure(
    summary: pd.DataFrame, path: Path, metrics: Sequence[MetricSpec], outcomes: Sequence[str] = ("RGSR",)
) -> Path:
    """Mean paired P0 - P1 difference per model with 95% intervals: the outcome rates, then each
    metric (percentage points for rates and "%" metrics, else in the metric's unit)."""
    measures = [(name, name, 100.0, "pp") for name in outcomes]
    measures += [(m.name, m.label, *((100.0, "pp") if m.percent else (1.0, m.unit))) for m in metrics]
    fig = Figure(figsize=(2.8 * len(measures), 1.6 + 0.35 * max(len(summary), 1)), layout="constrained")
    axes = fig.subplots(1, len(measures), squeeze=False, sharey=True)[0]
    models = list(summary["model"]) if len(summary) else []
    for ax, (measure, label, factor, unit) in zip(axes, measures):
        ax.set_title(_titled(f"{label}: P0 − P1", unit), fontsize=10)
        if not models:
            _empty(ax, "n/a: no matched P0/P1\nconflict pairs (n=0)")
            continue
        diff = factor * summary[measure].astype(float).to_numpy()
        low = factor * summary[f"{measure}_lo"].astype(float).to_numpy()
        high = factor * summary[f"{measure}_hi"].astype(float).to_numpy()
        n = summary[f"{measure}_n"].astype(int).to_numpy()
        tasks = summary[f"{measure}_clusters"].astype(int).to_numpy()
        y = np.arange(len(models))
        shown = np.nan_to_num(diff)
        whiskers = np.nan_to_num(np.vstack([diff - low, high - diff]))
        ax.barh(y, shown, color="#4C72B0", alpha=0.85, xerr=whiskers, error_kw={"elinewidth": 1, "capsize": 2})
        ax.axvline(0, color="black", linewidth=0.8)
        reach = np.concatenate([np.abs(low), np.abs(high), np.abs(diff)])
        span = float(np.nanmax(reach)) if np.isfinite(reach).any() else 0.0
        span = max(5.0, span) if unit == "pp" else (span or 1.0)  # at least +-5 pp around zero
        ax.set_xlim(-1.35 * span, 1.35 * span)
        for yi, d, k, g in zip(y, diff, n, tasks):
            note = f"n={k}, {g} task{'s' if g != 1 else ''}" if np.isfinite(d) else "n/a (n=0)"
            ax.text(1.33 * span, yi, note, va="center", ha="right", fontsize=6, color="0.3")
        ax.set_yticks(y, models, fontsize=8)
        ax.set_ylim(len(models) - 0.5, -0.5)
        ax.grid(axis="x", alpha=0.3)
    fig.suptitle(
        "Paired difference P0 − P1 per model (bar; > 0: higher under P0), 95% interval clustered by base task "
        "(whiskers)",
        fontsize=9,
    )
    return _save(fig, path)


def dsr_heatmap(family_level: pd.DataFrame, path: Path) -> Path:
    """dSR (%) per conflict family x level with its 95 % interval, one panel per model and prompt condition."""
    panels = (
        family_level[["model", "prompt"]].drop_duplicates().itertuples(index=False, name=None)
        if len(family_level)
        else []
    )
    panels = list(panels) or [("n/a", "")]
    ncols = min(4, len(panels))
    nrows = -(-len(panels) // ncols)
    present = set(family_level["family"].dropna()) if len(family_level) else set()
    families = [*FAMILIES, *sorted(str(f) for f in present - set(FAMILIES))]  # plugin families after ours
    fig = Figure(figsize=(3.4 * ncols, (1.0 + 0.6 * len(families)) * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False)
    image = None
    for ax, (model, prompt) in zip(axes.flat, panels):
        sub = (
            family_level[(family_level["model"] == model) & (family_level["prompt"] == prompt)]
            if len(family_level)
            else family_level
        )
        grid = np.full((len(families), len(LEVELS)), np.nan)
        counts = np.zeros_like(grid, dtype=int)
        bounds = np.full((*grid.shape, 2), np.nan)
        for row in sub.itertuples(index=False):
            if row.family in families and row.level in LEVELS:
                i, j = families.index(row.family), LEVELS.index(row.level)
                grid[i, j] = 100 * row.dSR
                counts[i, j] = row.pairs
                bounds[i, j] = (100 * row.dSR_lo, 100 * row.dSR_hi)
        image = ax.imshow(np.ma.masked_invalid(grid), cmap="RdBu", vmin=-100, vmax=100, aspect="auto")
        ax.set_facecolor("0.9")
        for i in range(len(families)):
            for j in range(len(LEVELS)):
                low, high = bounds[i, j]
                text = f"{grid[i, j]:.1f}\n[{low:.0f}, {high:.0f}]\nn={counts[i, j]}" if counts[i, j] else "n/a\nn=0"
                dark = np.isfinite(grid[i, j]) and abs(grid[i, j]) > 60
                ax.text(j, i, text, ha="center", va="center", fontsize=6, color="white" if dark else "black")
        ax.set_xticks(range(len(LEVELS)), LEVELS, fontsize=8)
        ax.set_yticks(range(len(families)), families, fontsize=8)
        ax.set_title(f"{model} {prompt.upper()}".strip() + ": dSR (%)", fontsize=9)
    for ax in list(axes.flat)[len(panels) :]:
        ax.set_visible(False)
    if image is not None:
        fig.colorbar(image, ax=axes, shrink=0.8, label="dSR = PCSR − RGSR (%)")
    return _save(fig, path)


def outcome_bars(family_level: pd.DataFrame, path: Path) -> Path:
    return _save(outcome_figure(family_level), path)


def outcome_figure(family_level: pd.DataFrame) -> Figure:
    """PCSR and RGSR (%) per level, one panel per conflict family and prompt condition, models side by side
    (solid: PCSR, hatched: RGSR), each bar with its 95 % interval (whiskers, clustered by base task) and its
    k/n; a level no pair reached says "n/a"."""
    prompts = [p for p in PROMPT_CONDITIONS if len(family_level) and p in set(family_level["prompt"])] or ["p0"]
    models = sorted(set(family_level["model"])) if len(family_level) else []
    present = set(family_level["family"].dropna()) if len(family_level) else set()
    families = [*FAMILIES, *sorted(str(f) for f in present - set(FAMILIES))]
    fig = Figure(figsize=(3.3 * len(families), 2.6 * len(prompts)), layout="constrained")
    axes = fig.subplots(len(prompts), len(families), squeeze=False, sharey=True)
    colours = [f"C{i % 10}" for i in range(len(models))]
    width = 0.8 / max(1, 2 * len(models))
    for r, prompt in enumerate(prompts):
        for c, family in enumerate(families):
            ax = axes[r, c]
            ax.set_title(f"{family} {prompt.upper()}", fontsize=9)
            ax.set_xticks(range(len(LEVELS)), LEVELS, fontsize=8)
            ax.set_xlim(-0.5, len(LEVELS) - 0.5)
            ax.set_ylim(0, 125)
            cell = (
                family_level[(family_level["prompt"] == prompt) & (family_level["family"] == family)] if models else []
            )
            if not len(cell):
                ax.text(0.5, 0.5, "n/a (n=0)", ha="center", va="center", transform=ax.transAxes, color="0.35")
                continue
            for m, model in enumerate(models):
                rows = {row.level: row for row in cell[cell["model"] == model].itertuples(index=False)}
                for o, (measure, hatch) in enumerate((("PCSR", None), ("RGSR", "///"))):
                    for j, level in enumerate(LEVELS):
                        x = j - 0.4 + width * (2 * m + o + 0.5)
                        row = rows.get(level)
                        if row is None or not row.pairs:
                            ax.text(x, 2, "n/a", ha="center", va="bottom", fontsize=5, rotation=90, color="0.4")
                            continue
                        value = 100 * getattr(row, measure)
                        low, high = 100 * getattr(row, f"{measure}_lo"), 100 * getattr(row, f"{measure}_hi")
                        ax.bar(x, value, width, color=colours[m], hatch=hatch, edgecolor="white", linewidth=0.3)
                        ax.errorbar(x, value, yerr=[[value - low], [high - value]], fmt="none", ecolor="0.2",
                                    elinewidth=0.6, capsize=1.2)  # fmt: skip
                        label = f"{getattr(row, f'{measure}_k')}/{row.pairs}"
                        ax.text(x, high + 1.5, label, ha="center", va="bottom", fontsize=5, rotation=90)
    for r in range(len(prompts)):
        axes[r, 0].set_ylabel("%", fontsize=8)
    handles = [_patch(colours[m], model) for m, model in enumerate(models)]
    handles += [_patch("0.6", "PCSR (solid)"), _hatched("RGSR (hatched)")]
    fig.legend(handles=handles, loc="outside lower center", ncols=min(6, len(handles)), fontsize=8, frameon=False)
    return fig


def _hatched(label: str):
    from matplotlib.patches import Patch

    return Patch(facecolor="0.6", hatch="///", edgecolor="white", label=label)
