"""PNG plots of scored trials: paths over the tank, each trial in its own frame, Fig. 7-style box plots."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from workbench.trials.scoring import STATION_STEP_M, STRAIGHT_DISTANCE_M

_COLOURS = ("#d62728", "#1f77b4", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _model_colours(models: Sequence[str]) -> dict[str, str]:
    return {m: _COLOURS[i % len(_COLOURS)] for i, m in enumerate(sorted(set(models)))}


def plot_tank(results, tank, path: str | Path) -> Path:
    """Every trial's cleaned path in the tank frame (world X across, Y along), start marked."""
    plt = _pyplot()
    cols = _model_colours([r.spec.model for r in results])
    fig, ax = plt.subplots(figsize=(5.2, 6.0))
    ax.add_patch(plt.Rectangle((0, 0), tank.width_m, tank.length_m, fill=False, lw=1.5, color="k"))
    seen = set()
    for r in results:
        ls = "-" if r.spec.task == "straight" else "--"
        lab = f"{r.spec.model} ({r.spec.task})"
        ax.plot(r.pose.x_m, r.pose.y_m, ls, color=cols[r.spec.model], lw=1.2,
                label=None if lab in seen else lab)
        seen.add(lab)
        o, f = r.frame.origin_m, r.frame.forward
        ax.annotate("", xy=o + 0.3 * f, xytext=o, arrowprops=dict(arrowstyle="->", color=cols[r.spec.model]))
        ax.text(o[0] + 0.05, o[1] - 0.12, r.spec.id, fontsize=6)
    ax.set_xlim(-0.2, tank.width_m + 0.2)
    ax.set_ylim(-0.2, tank.length_m + 0.2)
    ax.set_aspect("equal")
    ax.set_xlabel("tank X (m)")
    ax.set_ylabel("tank Y (m)")
    ax.set_title("trial paths in the tank")
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)


def plot_trial(result, path: str | Path) -> Path:
    """One trial in its own frame: straight with its stations, or turn with the fitted circle."""
    plt = _pyplot()
    tr = result.trajectory()
    after = tr["time_s"].to_numpy() >= 0
    x, y = tr["X_m"].to_numpy()[after], tr["Y_m"].to_numpy()[after]
    t = tr["time_s"].to_numpy()[after]
    sc = result.score
    fig, axes = plt.subplots(1, 2, figsize=(9, 4.2))
    ax = axes[0]
    sel = t <= sc.time_s
    ax.plot(x, y, color="0.7", lw=1, label="tracked (whole window)")
    ax.plot(x[sel], y[sel], color="C0", lw=1.5, label="scored part")
    filled = tr["filled"].to_numpy()[after]
    if filled.any():
        ax.plot(x[filled], y[filled], ".", color="C1", ms=3, label="gap filled")
    if result.spec.task == "straight":
        for level, _tc, xs in sc.stations:
            ax.plot([xs], [level], "o", color="C3", ms=4)
        for k in range(int(round(STRAIGHT_DISTANCE_M / STATION_STEP_M)) + 1):
            ax.axhline(k * STATION_STEP_M, color="0.85", lw=0.6, zorder=0)
        ax.set_title(f"straight: time {sc.time_s:.1f} s, MAE(X) {sc.mae_x_m:.3f} m")
    elif sc.circle_center is None:
        ax.set_title(f"turn: time {sc.time_s:.1f} s, no circle (the path is straight)")
    else:
        cx, cy = sc.circle_center
        a = np.linspace(0, 2 * np.pi, 200)
        ax.plot(cx + sc.radius_m * np.cos(a), cy + sc.radius_m * np.sin(a), "--", color="C3", label="fitted circle")
        ax.set_title(f"turn: time {sc.time_s:.1f} s, radius {sc.radius_m:.3f} m")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("X (m, right of start heading)")
    ax.set_ylabel("Y (m, along start heading)")
    ax.legend(fontsize=7)
    ax2 = axes[1]
    if result.spec.task == "straight":
        ax2.plot(t, y, color="C0")
        ax2.axhline(STRAIGHT_DISTANCE_M, color="k", lw=0.8)
        ax2.set_ylabel("Y (m)")
    else:
        h = tr["heading_change_deg"].to_numpy()[after]
        ax2.plot(t, np.abs(h), color="C0")
        ax2.axhline(360, color="k", lw=0.8)
        ax2.set_ylabel("|heading change| (deg)")
    ax2.axvline(sc.time_s, color="C3", lw=0.8)
    ax2.set_xlabel("time since start_s (s)")
    done = "completed" if sc.completed else "not completed"
    fig.suptitle(f"{result.spec.id}: {result.spec.model} solution {result.spec.solution} ({done})", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_boxplots(scores, path: str | Path, baseline: str | None = None) -> Path:
    """Per-model box plots of each score, with every solution as a labelled point (like the paper's Fig. 7)."""
    plt = _pyplot()
    models = sorted(scores["model"].unique().to_list(), key=lambda m: (m == baseline, m))
    cols = _model_colours(models)
    panels = [("straight", "time_s", "straight: time (s)"), ("straight", "mae_x_m", "straight: MAE(X) (m)"),
              ("turn", "time_s", "turn: time (s)"), ("turn", "radius_m", "turn: radius (m)")]
    fig, axes = plt.subplots(1, 4, figsize=(12, 3.8))
    for ax, (task, name, title) in zip(axes, panels, strict=True):
        _score_panel(ax, scores, models, cols, task, name, title)
    fig.suptitle("open-water trials per model (points: solutions, labelled by rank)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return Path(path)


def _score_panel(ax, scores, models: list[str], cols: dict[str, str], task: str, name: str, title: str) -> None:
    """One task's score per model: boxes of the finished trials, every solution a labelled point.

    A time of an unfinished trial is the cap, not a time: boxes use finished trials only and the
    unfinished ones are drawn apart, as crosses above a dashed "not finished" line.
    """
    timed = name == "time_s" and "completed" in scores.columns
    data, cap = _box_data(scores, models, task, name, timed)
    if any(len(d) for d in data):
        ax.boxplot([d if len(d) else [np.nan] for d in data], widths=0.5, showfliers=False)
    _solution_points(ax, scores, models, cols, task, name, timed, cap)
    if timed and cap is not None:
        ax.axhline(cap, color="0.4", ls="--", lw=0.8)
        ax.text(0.02, cap * 1.095, f"x: not finished in {cap:g} s", fontsize=7, va="center",
                transform=ax.get_yaxis_transform())
        ax.set_ylim(0.0, cap * 1.13)
    ax.set_xlim(0.5, len(models) + 0.5)
    ax.set_xticks(range(1, len(models) + 1))
    ax.set_xticklabels(list(models), fontsize=8)
    ax.set_title(title, fontsize=9)
    ax.grid(axis="y", alpha=0.3)


def _task_scores(scores, model: str, task: str, name: str):
    """The rows of one model and task that have the score ``name``."""
    return scores.filter((scores["model"] == model) & (scores["task"] == task)).drop_nulls(name)


def _box_data(scores, models: list[str], task: str, name: str, timed: bool) -> tuple[list[np.ndarray], float | None]:
    """Per model, the values the box is drawn from (finished trials only for a time), and the time cap seen."""
    data, cap = [], None
    for m in models:
        sub = _task_scores(scores, m, task, name)
        if timed:
            unfinished = sub.filter(~sub["completed"].cast(bool))
            if unfinished.height:
                cap = max(cap or 0.0, float(unfinished[name].max()))
            sub = sub.filter(sub["completed"].cast(bool))
        data.append(sub[name].to_numpy())
    return data, cap


def _solution_points(ax, scores, models: list[str], cols: dict[str, str], task: str, name: str, timed: bool,
                     cap: float | None) -> None:
    """Every solution as a jittered point labelled by rank; for a time, the unfinished as crosses above the cap."""
    rng = np.random.default_rng(0)
    for i, m in enumerate(models, start=1):
        sub = _task_scores(scores, m, task, name)
        done = sub["completed"].cast(bool).to_numpy() if timed else np.ones(sub.height, bool)
        xs = i + rng.uniform(-0.12, 0.12, sub.height)
        ys = sub[name].to_numpy().astype(float)
        if timed and cap is not None:
            ys = np.where(done, ys, cap * 1.05)
        ax.scatter(xs[done], ys[done], color=cols[m], s=18, zorder=3)
        if (~done).any():
            ax.scatter(xs[~done], ys[~done], color=cols[m], marker="x", s=30, zorder=3)
        for xx, yy, sol in zip(xs, ys, sub["solution"].to_list(), strict=True):
            ax.annotate(f"{sol}", (xx, yy), fontsize=6, xytext=(3, 2), textcoords="offset points")
