"""A small processed-format tunnel dataset from JointSinusoid and a known truth model (EF + memory).

Stands in for ingest output in unit tests: the columns of data contract section 3, one row per
65 Hz control tick, the truth = EF wrench passed through a first-order lag plus an fx
component and noise, so a sequence model has something the memoryless EF cannot capture.
"""

from __future__ import annotations

import itertools

import numpy as np
import polars as pl
from scipy.signal import lfilter

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.motion import JointSinusoid

RATE_HZ = 65.0


def truth_wrench(motion, tau_s: float = 0.08, noise: float = 0.0, rng=None) -> np.ndarray:
    w = EmpiricalFormula().wrench(motion)[0]
    a = np.exp(-motion.dt_s / tau_s)
    lagged = lfilter([1 - a], [1, -a], w, axis=0)
    out = 1.2 * lagged
    out[:, 0] = 0.4 * lagged[:, 1] + 0.02
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
