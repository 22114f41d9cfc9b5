"""Virtual-lab campaigns for the diagnosis tests: generate_tunnel -> ingest -> processed frame (cached)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

#: twelve parameter sets spread over the paper's ranges (theta_h_min, theta_k_max, f, phi)
GRID = [
    (10.0, -20.0, 0.3, math.pi / 3), (-10.0, -40.0, 0.4, 2 * math.pi / 3), (-30.0, -60.0, 0.5, math.pi),
    (-50.0, -80.0, 0.6, 4 * math.pi / 3), (10.0, -60.0, 0.6, 5 * math.pi / 3), (-30.0, -20.0, 0.3, 2 * math.pi / 3),
    (-10.0, -80.0, 0.5, math.pi / 3), (-50.0, -40.0, 0.4, math.pi), (10.0, -40.0, 0.5, 4 * math.pi / 3),
    (-30.0, -80.0, 0.4, 5 * math.pi / 3), (-50.0, -20.0, 0.5, 2 * math.pi / 3), (-10.0, -60.0, 0.3, math.pi),
]
SPEEDS = (0.0, 0.12, 0.25)
CYCLES = 4
SEED = 1


def grid(n_sets: int = 12) -> list[dict]:
    """The grid as manifest parameter sets."""
    return [dict(theta_h_min_deg=a, theta_h_max_deg=-100.0, theta_k_min_deg=80.0, theta_k_max_deg=b,
                 frequency_hz=f, phi_rad=p, alpha_rad=0.0) for a, b, f, p in GRID[:n_sets]]


def campaign(root: Path, effects=(), truth: str = "ef", n_sets: int = 12, seed: int = SEED) -> Path:
    """A small virtual-lab tunnel campaign folder."""
    import hashlib

    from workbench.virtual_lab.tunnel import generate_tunnel

    name = "c-" + hashlib.sha1(repr((tuple(effects), truth, n_sets, seed)).encode()).hexdigest()[:10]
    return generate_tunnel(root / name, seed=seed, truth=truth, effects=list(effects), grid=grid(n_sets),
                           cycles=CYCLES, flow_speeds=SPEEDS, campaign_id=name)


def processed(root: Path, effects=(), truth: str = "ef", n_sets: int = 12, seed: int = SEED):
    """The ingested frame of :func:`campaign` (the real chain)."""
    from workbench.ingest import ingest_campaign

    return ingest_campaign(campaign(root, effects, truth, n_sets, seed), params={"workers": 1}).frame


def heldout_mse(runs) -> np.ndarray:
    """Held-out MSE per channel of a list of RunResidual."""
    e = np.concatenate([r.resid[r.fit] for r in runs if r.heldout])
    return (e ** 2).mean(axis=0)
