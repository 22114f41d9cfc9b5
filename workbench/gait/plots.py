"""Pictures of an optimisation, as PNG bytes: Pareto front pairs, hypervolume per generation, best swims."""

from __future__ import annotations

import io
from typing import Sequence

import numpy as np

from workbench.gait.objectives import TaskSpec
from workbench.gait.run import Generation, non_dominated
from workbench.hydro.simulator import Trajectory


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    _pyplot().close(fig)
    return buf.getvalue()


def pareto_png(f: np.ndarray, n_retained: int, spec: TaskSpec, title: str) -> bytes:
    """The final population's objectives in three pairs; non-dominated and retained solutions marked.

    ``f`` is sorted best score first, so the first ``n_retained`` rows are the retained gaits.
    """
    plt = _pyplot()
    names = list(spec.names.values())
    front = np.zeros(len(f), bool)
    front[non_dominated(f)] = True
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for ax, (a, b) in zip(axes, ((0, 1), (0, 2), (1, 2)), strict=True):
        ax.scatter(f[~front, a], f[~front, b], s=14, c="0.7", label="dominated")
        ax.scatter(f[front, a], f[front, b], s=18, c="tab:blue", label="non-dominated")
        ax.scatter(f[:n_retained, a], f[:n_retained, b], s=60, facecolors="none", edgecolors="tab:red",
                   label=f"best {n_retained} by S")
        for i in range(min(n_retained, len(f))):
            ax.annotate(str(i + 1), (f[i, a], f[i, b]), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.set_xlabel(f"f{a + 1}: {names[a]}")
        ax.set_ylabel(f"f{b + 1}: {names[b]}")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    return _png(fig)


def history_png(history: Sequence[Generation], title: str) -> bytes:
    """Hypervolume (fixed reference point) and best score S per generation."""
    plt = _pyplot()
    gen = [g.gen for g in history]
    fig, ax = plt.subplots(figsize=(6.5, 4))
    ax.plot(gen, [g.hypervolume for g in history], "o-", c="tab:blue", ms=3)
    ax.set_xlabel("generation")
    ax.set_ylabel("hypervolume", color="tab:blue")
    ax2 = ax.twinx()
    ax2.plot(gen, [g.best_score for g in history], "s--", c="tab:red", ms=3)
    ax2.set_ylabel("best score S (lower is better)", color="tab:red")
    ax.grid(alpha=0.3)
    ax.set_title(title)
    fig.tight_layout()
    return _png(fig)


def trajectories_png(traj: Trajectory, spec: TaskSpec, title: str) -> bytes:
    """The retained gaits' swims seen from above (trial frame), with the finish line or start heading."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 6))
    for i in range(len(traj)):
        ax.plot(traj.x_m[i], traj.y_m[i], lw=1.2, label=f"#{i + 1}")
        ax.plot(traj.x_m[i, -1], traj.y_m[i, -1], "o", ms=3, c=ax.lines[-1].get_color())
    if spec.task == "straight":
        ax.axhline(spec.finish_distance_m, c="k", ls="--", lw=0.8, label="finish")
    ax.plot([0], [0], "k^", ms=8)
    ax.set_xlabel("X (m, right of start heading)")
    ax.set_ylabel("Y (m, along start heading)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    ax.set_title(title)
    fig.tight_layout()
    return _png(fig)
