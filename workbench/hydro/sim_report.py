"""Simulated swims as numbers (a per-gait summary) and a picture (paths seen from above)."""

from __future__ import annotations

import io
import math
from typing import Sequence

import numpy as np

from workbench.hydro.simulator import Trajectory


def summarise(traj: Trajectory, labels: Sequence[str], tail_s: float = 5.0) -> list[dict]:
    """Per gait: end pose, path length, mean forward speed and leg thrust over the last ``tail_s``."""
    tail = traj.t_s >= traj.t_s[-1] - tail_s
    path = np.hypot(np.diff(traj.x_m, axis=1), np.diff(traj.y_m, axis=1)).sum(axis=1)
    out = []
    for i, label in enumerate(labels):
        out.append({
            "gait": label,
            "params": traj.gaits.to_params()[i],
            "final_x_m": float(traj.x_m[i, -1]), "final_y_m": float(traj.y_m[i, -1]),
            "final_yaw_deg": float(np.degrees(traj.yaw_rad[i, -1])),
            "path_length_m": float(path[i]),
            "mean_forward_speed_mps": float(traj.vy_mps[i, tail].mean()),
            "mean_yaw_rate_dps": float(np.degrees(traj.yaw_rate_rps[i, tail].mean())),
            "mean_leg_thrust_n": float(traj.leg_thrust_n[i, tail].mean()),
            "fixed_point_residual_mps": float(traj.residual_mps[i]), "converged": bool(traj.converged[i]),
        })
    return out


def paths_figure_png(traj: Trajectory, labels: Sequence[str], max_legend: int = 12) -> bytes:
    """PNG bytes: each gait's path in the trial frame (x right, y ahead), heading arrows at the end."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.0, 6.0), dpi=110)
    cmap = plt.get_cmap("viridis" if len(labels) > 10 else "tab10")
    span = max(float(np.max(np.abs(traj.x_m))), float(np.max(np.abs(traj.y_m))), 0.05)
    for i, label in enumerate(labels):
        colour = cmap(i / max(1, len(labels) - 1)) if len(labels) > 10 else cmap(i % 10)
        ok = bool(traj.converged[i])
        ax.plot(traj.x_m[i], traj.y_m[i], color=colour, lw=1.2, ls="-" if ok else "--",
                label=(label if ok else f"{label} (NOT converged)") if i < max_legend else None)
        yaw = traj.yaw_rad[i, -1]
        ax.annotate("", xy=(traj.x_m[i, -1] - 0.06 * span * math.sin(yaw), traj.y_m[i, -1] + 0.06 * span * math.cos(yaw)),
                    xytext=(traj.x_m[i, -1], traj.y_m[i, -1]), arrowprops={"arrowstyle": "->", "color": colour})
    ax.plot([0], [0], "ko", ms=4)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m, right of the start heading)")
    ax.set_ylabel("y (m, along the start heading)")
    ax.set_title(f"simulated paths, {traj.t_s[-1]:.0f} s, leg model {traj.model}", fontsize=10)
    ax.grid(alpha=0.3)
    if labels:
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()
