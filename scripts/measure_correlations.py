"""Measure how a store's pairs are correlated within a base task, and write them where the package reads them.

    conflictbench model=subject run.init_states=3 run.cases_per_cell=4 run.out=.cache/icc-store
    .venv/bin/python scripts/measure_correlations.py .cache/icc-store

For each measure (conflict success, dSR per pair, TS, and reference success over references), the mean
correlation between two pairs of one base task that share
  - the case (other initial states): ``case``,
  - the initial state, so the reference (other cases): ``state``,
  - nothing but the task: ``task``,
each the mean of (x_i - mean)(x_j - mean) over such pairs (i != j) over the variance of x. For the binary
outcomes the same on the latent (probit) scale, by the tetrachoric correlation at the observed rate: the
variance components of the coverage tests' generator (tests/crossed_effects.py). dSR's three give the plan
line's bound and README's power table (conflictbench/metrics/design.py). Writes
conflictbench/metrics/correlations.json (or --out) and prints the figures.
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import shlex
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import optimize, stats

ROOT = Path(__file__).resolve().parents[1]


def class_correlations(frame: pd.DataFrame, column: str) -> dict[str, float]:
    """Mean pairwise correlation of ``column`` within a task by what two pairs share (case, state, task only)."""
    values = frame[column].to_numpy(dtype=np.float64)
    keep = np.isfinite(values)
    frame, values = frame[keep], values[keep]
    deviation = values - values.mean()
    variance = float(np.mean(deviation**2))

    def cross(keys: list[str]) -> tuple[float, float]:
        sums = pd.DataFrame({"d": deviation, "d2": deviation**2, "n": 1.0}).groupby(
            [frame[k].to_numpy() for k in keys]
        ).sum()  # fmt: skip
        return float((sums["d"] ** 2 - sums["d2"]).sum()), float((sums["n"] ** 2 - sums["n"]).sum())

    task, n_task = cross(["suite", "task_id"])
    case, n_case = cross(["suite", "task_id", "case_id"]) if "case_id" in frame else (0.0, 0.0)
    state, n_state = cross(["suite", "task_id", "init_state"])
    only, n_only = task - case - state, n_task - n_case - n_state
    out = {"task": only / n_only / variance if n_only else float("nan")}
    if "case_id" in frame:
        out["case"] = case / n_case / variance if n_case else float("nan")
        out["state"] = state / n_state / variance if n_state else float("nan")
    out["within_task"] = task / n_task / variance if n_task else float("nan")
    out["mean"] = float(values.mean())
    out["variance"] = variance
    out["n"] = int(len(values))
    return out


def cross_correlations(frame: pd.DataFrame) -> dict[str, float]:
    """Correlation of a reference's success with a conflict episode's of the same task: at the same initial
    state (its own reference, ``state``) and at another (``task``)."""
    y_ref = frame["reference_success"].to_numpy(dtype=np.float64)
    y_con = frame["conflict_success"].to_numpy(dtype=np.float64)
    references = frame.drop_duplicates(["suite", "task_id", "init_state"])
    p_ref, p_con = float(references["reference_success"].astype(float).mean()), float(y_con.mean())
    scale = np.sqrt(p_ref * (1 - p_ref) * p_con * (1 - p_con))
    same = float(np.mean((y_ref - p_ref) * (y_con - p_con)))
    ref_dev = (references["reference_success"].astype(float) - p_ref).groupby(
        [references["suite"], references["task_id"]]).sum()  # fmt: skip
    con_dev = pd.Series(y_con - p_con).groupby([frame["suite"].to_numpy(), frame["task_id"].to_numpy()]).sum()
    per_task_refs = references.groupby(["suite", "task_id"]).size()
    per_task_cons = frame.groupby(["suite", "task_id"]).size()
    joined = pd.concat({"r": ref_dev, "c": con_dev, "nr": per_task_refs, "nc": per_task_cons}, axis=1).fillna(0)
    all_products = float((joined["r"] * joined["c"]).sum()) - same * len(frame)
    count = float((joined["nr"] * joined["nc"]).sum()) - len(frame)
    other = all_products / count if count else float("nan")
    return {"state": same / scale, "task": other / scale, "reference_rate": p_ref, "conflict_rate": p_con}


def tetrachoric(rate: float, correlation: float, other_rate: float | None = None) -> float:
    """The latent correlation of two probit-thresholded normals that gives ``correlation`` between the 0/1
    outcomes at ``rate`` (and ``other_rate`` for the second, default the same)."""
    other_rate = rate if other_rate is None else other_rate
    if not (0 < rate < 1 and 0 < other_rate < 1) or not np.isfinite(correlation):
        return float("nan")
    h, k = stats.norm.ppf(rate), stats.norm.ppf(other_rate)
    both = rate * other_rate + correlation * np.sqrt(rate * (1 - rate) * other_rate * (1 - other_rate))

    def gap(r: float) -> float:
        return stats.multivariate_normal.cdf([h, k], mean=[0, 0], cov=[[1, r], [r, 1]]) - both

    low, high = -0.999, 0.999
    if gap(low) > 0 or gap(high) < 0:
        return float(np.clip(correlation, -1, 1))
    return float(optimize.brentq(gap, low, high, xtol=1e-6))


def between_models(a: pd.DataFrame, b: pd.DataFrame) -> dict[str, float]:
    """How alike two models' outcomes are on the same episode: the correlation of their reference successes (same
    task and initial state), conflict successes and TS (same pair), observed and, for the outcomes, latent."""
    keys = ["suite", "task_id", "init_state", "case_id"]
    both = a.merge(b, on=keys, suffixes=("_a", "_b"))
    refs = both.drop_duplicates(["suite", "task_id", "init_state"])
    out: dict[str, float] = {"pairs": int(len(both)), "references": int(len(refs))}
    both = both.assign(
        dSR_a=both["reference_success_a"].astype(float) - both["conflict_success_a"].astype(float),
        dSR_b=both["reference_success_b"].astype(float) - both["conflict_success_b"].astype(float),
    )
    for name, frame, column in (("reference_success", refs, "reference_success"),
                                ("conflict_success", both, "conflict_success"), ("ts", both, "ts"),
                                ("dSR", both, "dSR")):  # fmt: skip
        x, y = frame[f"{column}_a"].astype(float), frame[f"{column}_b"].astype(float)
        r = float(np.corrcoef(x, y)[0, 1])
        out[name] = r
        if name.endswith("success"):
            out[f"{name}_latent"] = tetrachoric(float(x.mean()), r, float(y.mean()))
    # the per-pair difference of dSR between the two: its variance and how it is correlated within a task
    difference = both.assign(difference=both["dSR_a"] - both["dSR_b"])
    out["dSR_difference"] = class_correlations(difference, "difference")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("store")
    parser.add_argument("--model", help="the model (as the report labels it) to measure, where the store has several")
    parser.add_argument("--second", help="a second model of the store: how alike the two models' outcomes are")
    parser.add_argument("--prompt", default="p0", help="the prompt condition measured (pairs of one only: default p0)")
    parser.add_argument("--out", default=str(ROOT / "conflictbench" / "metrics" / "correlations.json"))
    args = parser.parse_args(argv)

    import conflictbench
    from conflictbench.report.from_store import store_frame
    from conflictbench.report.summary import select_metrics
    from conflictbench.store import EpisodeStore

    plugins = conflictbench.plugins()
    store = EpisodeStore(args.store)
    everything, models = store_frame(store, plugins, select_metrics(plugins, ["ts"]))
    everything = everything[everything["prompt"] == args.prompt]  # two prompts' pairs would share case and state
    model = args.model or (models[0] if len(models) == 1 else None)
    if model not in models or (args.second and args.second not in models):
        print(f"name --model (and --second) among the store's models: {', '.join(models)}", file=sys.stderr)
        return 2
    frame = everything[everything["model"] == model]
    frame = frame.assign(
        conflict=frame["conflict_success"].astype(float),
        dSR=frame["reference_success"].astype(float) - frame["conflict_success"].astype(float),
    )
    references = frame.drop_duplicates(["suite", "task_id", "init_state", "prompt"]).assign(
        reference=lambda f: f["reference_success"].astype(float)
    )
    result = {
        "conflict_success": class_correlations(frame, "conflict"),
        "dSR": class_correlations(frame, "dSR"),
        "ts": class_correlations(frame, "ts"),
        "reference_success": class_correlations(references.drop(columns=["case_id"]), "reference"),
    }
    latent = {}
    for name in ("conflict_success", "reference_success"):
        measured = result[name]
        latent[name] = {
            k: tetrachoric(measured["mean"], measured[k]) for k in ("task", "case", "state") if k in measured
        }
    cross = cross_correlations(frame)
    result["reference_conflict"] = cross
    rates = cross["reference_rate"], cross["conflict_rate"]
    task = tetrachoric(rates[0], cross["task"], rates[1])
    latent["cross"] = {"task": task, "state": tetrachoric(rates[0], cross["state"], rates[1]) - task}
    result["latent"] = latent
    if args.second:
        result["between_models"] = between_models(frame, everything[everything["model"] == args.second])
        result["between_models"]["models"] = [model, args.second]
    result["provenance"] = {
        "command": "scripts/measure_correlations.py " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:])),
        "model": model,
        "episodes": int(len(frame) + len(references)),
        "pairs": int(len(frame)),
        "base_tasks": int(frame[["suite", "task_id"]].drop_duplicates().shape[0]),
        "cases": int(frame["case_id"].nunique()),
        "measured": datetime.date.today().isoformat(),
        "machine": platform.processor() or platform.machine(),
    }
    text = json.dumps(result, indent=2, sort_keys=True) + "\n"
    Path(args.out).write_text(text, encoding="utf-8")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
