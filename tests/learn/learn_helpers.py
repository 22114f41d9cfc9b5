"""Helpers of the learn tests: a small processed-format tunnel dataset, the real config shrunk, subprocess env.

The dataset stands in for ingest output in unit tests: the columns of data contract section 3,
one row per 65 Hz control tick of a JointSinusoid motion, the wrench from the virtual lab's
ground truth (``TrueLegModel("rich")``: added mass growing with KC, Wagner lag, link drag,
weight and buoyancy, ...) plus noise, so a sequence model has something the EF cannot capture.
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path

import numpy as np
import polars as pl

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.hydro.motion import JointSinusoid
from workbench.virtual_lab.physics import TrueLegModel

RATE_HZ = 65.0
CONFIG = Path(__file__).resolve().parents[2] / "pipelines" / "learn.yaml"


def truth_wrench(motion, noise: float = 0.0, rng=None) -> np.ndarray:
    """The virtual lab's ground truth (richer than the EF) plus load-cell-like noise."""
    out = TrueLegModel("rich").wrench(motion)[0]
    if noise and rng is not None:
        out = out + rng.normal(0, noise, out.shape) * np.array([1, 1, 1, 0.02, 0.02, 0.02])
    return out


def make_frame(theta_h_min=(10.0, -10.0, -30.0, -50.0), theta_k_max=(-20.0, -40.0, -60.0),
               freqs=(0.5,), phis=(1.0472,), speeds=(0.1, 0.2), cycles: float = 3.0, seed: int = 0,
               campaign_id: str = "synth", noise: float = 0.003, interpolated_speeds=()) -> pl.DataFrame:
    rng = np.random.default_rng(seed)
    parts = []
    k = 0
    sets = list(itertools.product(theta_h_min, theta_k_max, freqs, phis))
    for (hmin, kmax, f, phi) in sets:
        for speed, interp in [(s, False) for s in speeds] + [(s, True) for s in interpolated_speeds]:
            k += 1
            p = dict(theta_h_min_deg=hmin, theta_h_max_deg=-100.0, theta_k_min_deg=80.0, theta_k_max_deg=kmax,
                     frequency_hz=f, phi_rad=phi, alpha_rad=0.0)
            js = JointSinusoid.from_params(p)
            t = np.arange(int(cycles / f * RATE_HZ)) / RATE_HZ
            m = js.motion(t, speed)
            w = truth_wrench(m, noise=noise, rng=rng)
            cols = {"campaign_id": campaign_id, "run_id": f"r{k:04d}", "time_s": t, "flow_speed_mps": speed,
                    "theta_h_deg": m.theta_h_deg[0], "theta_k_deg": m.theta_k_deg[0],
                    "omega_h_dps": m.omega_h_dps[0], "omega_k_dps": m.omega_k_dps[0],
                    **{c: w[:, i] for i, c in enumerate(WRENCH_CHANNELS)}, "interpolated": interp, **p}
            parts.append(pl.DataFrame({c: np.broadcast_to(v, t.shape) if np.ndim(v) == 0 else v
                                       for c, v in cols.items()}))
    return pl.concat(parts)


def tiny_config(paths, root: Path, **over):
    """The real pipelines/learn.yaml train section, shrunk to a few CPU batches, tracked in ``root``."""
    from workbench.learn.config import load_config

    base = {"data.paths": [str(p) for p in paths], "data.train_windows_per_epoch": 1536, "data.batch_size": 128,
            "model.hidden_size": 16, "trainer.max_epochs": 2, "trainer.max_time_s": None,
            "trainer.early_stop_patience": 0, "tracking.tracking_uri": f"sqlite:///{root / 'mlflow.db'}",
            "model_dir": str(root / "datasets" / "models" / "fed-lstm")}
    base.update(over)
    return load_config(CONFIG).with_overrides(base)


def subprocess_env(root: Path) -> dict:
    """Environment of a fresh process in the isolated project."""
    env = dict(os.environ)
    env.update(WORKBENCH_HOME=str(root), MLFLOW_TRACKING_URI=f"sqlite:///{root / 'mlflow.db'}", MPLBACKEND="Agg")
    return env
