"""Score tables, per-model statistics and the Table IV-style comparison of two models (pure polars).

Relative improvement of a model over the baseline, for a score where lower is better (every
score here: times, MAE, and the turning radius, a tighter turn being the better one):
``(baseline - model) / baseline``. The paper's Table IV in these terms: FED-LSTM's best straight
solution has 47.1% lower MAE ((0.17 - 0.09) / 0.17) and 8.7% shorter time ((23 - 21) / 23) than
EF's, and its best turn a 47.6% shorter time ((42 - 22) / 42).
"""

from __future__ import annotations

import math
from typing import Iterable, Sequence

import numpy as np

#: scores.csv columns, exactly as the contract (section 4) lists them
SCORE_COLUMNS = ("trial_id", "model", "solution", "task", "time_s", "mae_x_m", "radius_m", "completed")
#: the scores of each task
TASK_SCORES = {"straight": ("time_s", "mae_x_m"), "turn": ("time_s", "radius_m")}


def scores_frame(rows: Iterable[dict]):
    """A scores table (polars) with the contract's columns and types from dicts of those keys."""
    import polars as pl

    schema = {"trial_id": pl.Utf8, "model": pl.Utf8, "solution": pl.Int64, "task": pl.Utf8, "time_s": pl.Float64,
              "mae_x_m": pl.Float64, "radius_m": pl.Float64, "completed": pl.Boolean}
    rows = [{k: r.get(k) for k in SCORE_COLUMNS} for r in rows]
    return pl.DataFrame(rows, schema=schema)


def relative_improvement(model_value: float | None, baseline_value: float | None) -> float | None:
    """``(baseline - model) / baseline``: positive when the model's (lower-is-better) score is lower."""
    if model_value is None or baseline_value is None or not np.isfinite(model_value) \
            or not np.isfinite(baseline_value) or baseline_value == 0:
        return None
    return float((baseline_value - model_value) / baseline_value)


def _stats(values: Sequence[float]) -> dict | None:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], float)
    if v.size == 0:
        return None
    return {"mean": float(v.mean()), "median": float(np.median(v)), "min": float(v.min()), "max": float(v.max())}


def model_statistics(scores) -> dict:
    """Per model and task: count, completed count, and mean/median/min/max of each score."""
    out: dict = {}
    for model in sorted(scores["model"].unique().to_list()):
        out[model] = {}
        for task, names in TASK_SCORES.items():
            sub = scores.filter((scores["model"] == model) & (scores["task"] == task))
            if sub.height == 0:
                continue
            entry = {"n": sub.height, "completed": int(sub["completed"].sum())}
            for name in names:
                entry[name] = _stats(sub[name].to_list())
            out[model][task] = entry
    return out


def pick_baseline(models: Sequence[str], requested: str | None = None) -> str | None:
    """The model the others are compared against: the requested one, else EF when present, else the first."""
    models = sorted(models)
    if not models:
        return None
    if requested:
        for m in models:
            if m.lower() == requested.lower():
                return m
        return None
    for m in models:
        if m.lower() == "ef":
            return m
    return models[0]


def _best(sub) -> dict | None:
    """The row of the best-ranked (lowest ``solution``) scored trial."""
    if sub.height == 0:
        return None
    return sub.sort(["solution", "trial_id"]).row(0, named=True)


def compare_models(scores, baseline: str | None = None) -> dict:
    """Relative improvements of every other model over the baseline, per task and score.

    ``best``: the best-ranked solution each model has scored (rank 1 when it was scored);
    ``mean`` and ``median``: over all retained (scored) solutions of each model.
    """
    models = sorted(scores["model"].unique().to_list())
    base = pick_baseline(models, baseline)
    out = {"baseline": base, "definition": "relative improvement of MODEL over BASELINE = (baseline - model) / "
           "baseline, per score (lower is better for every score); positive means MODEL is better", "models": {}}
    if base is None:
        return out
    for model in models:
        if model == base:
            continue
        per_task = {}
        for task, names in TASK_SCORES.items():
            mine = scores.filter((scores["model"] == model) & (scores["task"] == task))
            theirs = scores.filter((scores["model"] == base) & (scores["task"] == task))
            if mine.height == 0 or theirs.height == 0:
                continue
            bm, bb = _best(mine), _best(theirs)
            entry = {"best": {"solution": {model: bm["solution"], base: bb["solution"]}}}
            for name in names:
                entry["best"][name] = {model: bm[name], base: bb[name],
                                       "improvement": relative_improvement(bm[name], bb[name])}
            for agg in ("mean", "median"):
                entry[agg] = {}
                for name in names:
                    a, b = _stats(mine[name].to_list()), _stats(theirs[name].to_list())
                    va, vb = (a or {}).get(agg), (b or {}).get(agg)
                    entry[agg][name] = {model: va, base: vb, "improvement": relative_improvement(va, vb)}
            per_task[task] = entry
        out["models"][model] = per_task
    return out


def _fmt(v, digits: int) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.{digits}f}"


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:+.1f}%"


def comparison_markdown(scores, comparison: dict) -> str:
    """A Table IV-like markdown table (per model and solution) followed by the improvements."""
    lines = ["| Model | T_S (s) | MAE(X) (m) | T_T (s) | r_T (m) |", "|---|---|---|---|---|"]
    models = sorted(scores["model"].unique().to_list(), key=lambda m: (m == comparison.get("baseline"), m))
    for model in models:
        sub = scores.filter(scores["model"] == model)
        for sol in sorted(sub["solution"].unique().to_list()):
            row = sub.filter(sub["solution"] == sol)
            st = row.filter(row["task"] == "straight")
            tu = row.filter(row["task"] == "turn")

            def cell(frame, name, digits, mark_unfinished=False):
                if frame.height == 0:
                    return "-"
                r = frame.row(0, named=True)
                txt = _fmt(r[name], digits)
                return txt + ("*" if mark_unfinished and not r["completed"] else "")

            lines.append(f"| {model}_{sol} | {cell(st, 'time_s', 1, True)} | {cell(st, 'mae_x_m', 3)} | "
                         f"{cell(tu, 'time_s', 1, True)} | {cell(tu, 'radius_m', 3)} |")
    lines.append("")
    lines.append("`*` not completed within 60 s (scored as 60 s).")
    base = comparison.get("baseline")
    for model, tasks in comparison.get("models", {}).items():
        lines += ["", f"Relative improvement of {model} over {base}, (baseline - model) / baseline "
                  "(positive: lower, i.e. better):", "",
                  "| | T_S | MAE(X) | T_T | r_T |", "|---|---|---|---|---|"]
        for agg, label in (("best", "best solution"), ("mean", "mean of retained"), ("median", "median of retained")):
            st = tasks.get("straight", {}).get(agg, {})
            tu = tasks.get("turn", {}).get(agg, {})
            lines.append(f"| {label} | {_pct(st.get('time_s', {}).get('improvement'))} | "
                         f"{_pct(st.get('mae_x_m', {}).get('improvement'))} | "
                         f"{_pct(tu.get('time_s', {}).get('improvement'))} | "
                         f"{_pct(tu.get('radius_m', {}).get('improvement'))} |")
    return "\n".join(lines) + "\n"
