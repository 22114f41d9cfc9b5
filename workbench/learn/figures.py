"""The paper's comparison figures and the learning curve, as matplotlib Figures (no pyplot state).

* :func:`prediction_figure` — Fig. 4 style: the web's path and orientation in the leg plane, the
  joint angles, and the six measured channels (red) against the EF (blue) and the FED-LSTM
  (green), over the last cycles of one held-out run.
* :func:`mse_boxplot` — Fig. 5 style: per-run MSE of each model by flow speed, for f_y, f_z, tau_x.
* :func:`learning_curve` — training and validation loss and the learning rate per epoch.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS

COLOURS = {"measured": "#d62728", "ef": "#1f77b4", "lstm": "#2ca02c"}
LABELS = {"fx_n": "$f_x$ (N)", "fy_n": "$f_y$ (N)", "fz_n": "$f_z$ (N)",
          "tx_nm": r"$\tau_x$ (N m)", "ty_nm": r"$\tau_y$ (N m)", "tz_nm": r"$\tau_z$ (N m)"}
#: the squared units of each channel's MSE
MSE_LABELS = {"fx_n": "$f_x$ (N$^2$)", "fy_n": "$f_y$ (N$^2$)", "fz_n": "$f_z$ (N$^2$)",
              "tx_nm": r"$\tau_x$ (N$^2$ m$^2$)", "ty_nm": r"$\tau_y$ (N$^2$ m$^2$)", "tz_nm": r"$\tau_z$ (N$^2$ m$^2$)"}


def _figure(w: float, h: float):
    from matplotlib.figure import Figure

    return Figure(figsize=(w, h), layout="constrained")


def prediction_figure(title: str, time_s: np.ndarray, motion, measured: np.ndarray,
                      predictions: Mapping[str, np.ndarray], *, first: int = 0, mse: Mapping[str, Mapping] | None = None,
                      note: str | None = None):
    """Measured vs predicted wrench for one run from tick ``first`` on; ``motion`` is its one-row LegMotion."""
    from workbench.hydro.kinematics import DEFAULT_GEOMETRY, leg_state

    sl = slice(first, None)
    t = time_s[sl] - time_s[first]
    fig = _figure(13, 9.5)
    grid = fig.add_gridspec(3, 3)
    ax = fig.add_subplot(grid[0, 0])
    st = leg_state(np.radians(motion.theta_h_deg[0][sl]), np.radians(motion.theta_k_deg[0][sl]))
    ax.plot(st.q[:, 0], st.q[:, 1], color="0.4", lw=1)
    half = DEFAULT_GEOMETRY.web_side_m / 2
    for i in range(0, len(t), max(len(t) // 24, 1)):
        p, d = st.q[i], st.tangent[i]
        ax.plot([p[0] - half * d[0], p[0] + half * d[0]], [p[1] - half * d[1], p[1] + half * d[1]],
                color="#9467bd", lw=1.5, alpha=0.7)
    ax.plot(0, 0, "ko", ms=4)
    ax.set_aspect("equal")
    ax.set_xlabel("X forward (m)")
    ax.set_ylabel("Y up (m)")
    ax.set_title("web midpoint Q and web orientation", fontsize=9)
    ax = fig.add_subplot(grid[0, 1:])
    ax.plot(t, motion.theta_h_deg[0][sl], label=r"$\theta_H$")
    ax.plot(t, motion.theta_k_deg[0][sl], label=r"$\theta_K$")
    ax.set_ylabel("joint angle (deg)")
    ax.legend(loc="upper right", fontsize=8)
    for i, ch in enumerate(WRENCH_CHANNELS):
        ax = fig.add_subplot(grid[1 + i // 3, i % 3])
        ax.plot(t, measured[sl, i], color=COLOURS["measured"], lw=1.6, label="measured (GT)")
        for name, pred in predictions.items():
            ax.plot(t, pred[sl, i], color=COLOURS.get(name), lw=1.2, label=name.upper())
        ax.set_ylabel(LABELS[ch])
        if i >= 3:
            ax.set_xlabel("time (s)")
        if mse:
            ax.set_title("  ".join(f"{n.upper()} {mse[n][ch]:.2g}" for n in predictions if n in mse), fontsize=8)
        if i == 0:
            ax.legend(fontsize=8)
    fig.suptitle(title + (f"\n{note}" if note else ""), fontsize=10)
    return fig


def mse_boxplot(metrics: Mapping[str, Mapping], channels: Sequence[str] = ("fy_n", "fz_n", "tx_nm"),
                models: Sequence[str] = ("ef", "lstm")):
    """Per-run MSE by flow speed, one panel per channel, the models side by side (log scale)."""
    models = [m for m in models if m in metrics]
    speeds = sorted({r["flow_speed_mps"] for m in models for r in metrics[m]["by_run"]})
    fig = _figure(4.2 * len(channels), 3.8)
    axes = fig.subplots(1, len(channels), squeeze=False)[0]
    width = 0.8 / max(len(models), 1)
    for ax, ch in zip(axes, channels, strict=False):
        for j, m in enumerate(models):
            data = [[r["mse"][ch] for r in metrics[m]["by_run"] if abs(r["flow_speed_mps"] - s) < 1e-6] for s in speeds]
            pos = np.arange(len(speeds)) + (j - (len(models) - 1) / 2) * width
            bp = ax.boxplot(data, positions=pos, widths=width * 0.9, patch_artist=True, showfliers=True)
            for box in bp["boxes"]:
                box.set_facecolor(COLOURS.get(m, "0.7"))
                box.set_alpha(0.55)
            ax.plot([], [], color=COLOURS.get(m, "0.7"), lw=6, alpha=0.55, label=m.upper())
        ax.set_xticks(np.arange(len(speeds)), [f"{s:.2f}" for s in speeds])
        ax.set_yscale("log")
        ax.set_xlabel("flow speed (m/s)")
        ax.set_title(f"MSE of {MSE_LABELS[ch]}", fontsize=10)
    axes[0].set_ylabel("per-run MSE")
    axes[0].legend(fontsize=8)
    return fig


def learning_curve(history: Sequence[Mapping[str, float]]):
    """Training/validation loss (log) and learning rate per epoch."""
    fig = _figure(6, 3.6)
    ax = fig.add_subplot(1, 1, 1)
    ep = [h["epoch"] for h in history]
    ax.plot(ep, [h["train_loss"] for h in history], "o-", label="train")
    ax.plot(ep, [h["val_loss"] for h in history], "s-", label="validation")
    ax.set_yscale("log")
    ax.set_xlabel("epoch")
    ax.set_ylabel("MSE (normalised)")
    ax2 = ax.twinx()
    ax2.step(ep, [h["lr"] for h in history], where="mid", color="0.5", lw=1, label="lr")
    ax2.set_yscale("log")
    ax2.set_ylabel("learning rate", color="0.5")
    ax.legend(fontsize=8)
    return fig
