"""Joint-angle histories handed to leg force models, and the paper's prescribed sinusoid (equation 3)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np


@dataclass(frozen=True)
class LegMotion:
    """A batch of joint-angle histories on a uniform tick grid, with the flow speed per tick.

    Arrays are ``(B, T)``: B legs or runs, T ticks ``dt_s`` apart. Angles in degrees, rates in
    deg/s (the processed dataset's units). Accelerations are optional: when absent they are
    taken as the centred difference of the rates.
    """

    dt_s: float
    theta_h_deg: np.ndarray
    theta_k_deg: np.ndarray
    omega_h_dps: np.ndarray
    omega_k_dps: np.ndarray
    flow_speed_mps: np.ndarray
    alpha_h_dps2: np.ndarray | None = None
    alpha_k_dps2: np.ndarray | None = None

    @classmethod
    def from_arrays(cls, dt_s: float, theta_h_deg, theta_k_deg, omega_h_dps, omega_k_dps, flow_speed_mps,
                    alpha_h_dps2=None, alpha_k_dps2=None) -> "LegMotion":
        """Build from 1-D or 2-D arrays (1-D: one row); scalars broadcast, per-row values come as ``(B, 1)``."""
        th = np.atleast_2d(np.asarray(theta_h_deg, float))
        shape = th.shape

        def fit(x):
            # scalars broadcast; a 1-D array is a time series; per-row values come as (B, 1)
            if x is None:
                return None
            return np.broadcast_to(np.asarray(x, float), shape).astype(float)

        return cls(dt_s=float(dt_s), theta_h_deg=th, theta_k_deg=fit(theta_k_deg), omega_h_dps=fit(omega_h_dps),
                   omega_k_dps=fit(omega_k_dps), flow_speed_mps=fit(flow_speed_mps),
                   alpha_h_dps2=fit(alpha_h_dps2), alpha_k_dps2=fit(alpha_k_dps2))

    @property
    def shape(self) -> tuple[int, int]:
        """(B, T)."""
        return self.theta_h_deg.shape

    def accelerations_dps2(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint angular accelerations (deg/s^2), given or differenced from the rates."""
        if self.alpha_h_dps2 is not None and self.alpha_k_dps2 is not None:
            return self.alpha_h_dps2, self.alpha_k_dps2
        edge = 2 if self.shape[1] > 2 else 1
        return (np.gradient(self.omega_h_dps, self.dt_s, axis=-1, edge_order=edge),
                np.gradient(self.omega_k_dps, self.dt_s, axis=-1, edge_order=edge))

    def rows(self, idx) -> "LegMotion":
        """A sub-batch."""
        def pick(x):
            return None if x is None else x[idx]

        return LegMotion(self.dt_s, pick(self.theta_h_deg), pick(self.theta_k_deg), pick(self.omega_h_dps),
                         pick(self.omega_k_dps), pick(self.flow_speed_mps), pick(self.alpha_h_dps2),
                         pick(self.alpha_k_dps2))


@dataclass(frozen=True)
class JointSinusoid:
    """The paper's prescribed motion (equation 3) for one leg; angles in degrees, phases in rad."""

    theta_h_min_deg: float
    theta_h_max_deg: float
    theta_k_min_deg: float
    theta_k_max_deg: float
    frequency_hz: float
    phi_rad: float
    alpha_rad: float = 0.0

    @classmethod
    def from_params(cls, p: Mapping[str, float]) -> "JointSinusoid":
        """From a manifest run's parameters (contract names)."""
        return cls(p["theta_h_min_deg"], p["theta_h_max_deg"], p["theta_k_min_deg"], p["theta_k_max_deg"],
                   p["frequency_hz"], p["phi_rad"], p.get("alpha_rad", 0.0))

    def evaluate(self, t_s: np.ndarray) -> tuple[np.ndarray, ...]:
        """theta_h, theta_k (deg), omega_h, omega_k (deg/s), alpha_h, alpha_k (deg/s^2) at times t."""
        t = np.asarray(t_s, float)
        w = 2 * np.pi * self.frequency_hz
        ah = (self.theta_h_max_deg - self.theta_h_min_deg) / 2
        mh = (self.theta_h_max_deg + self.theta_h_min_deg) / 2
        ak = (self.theta_k_max_deg - self.theta_k_min_deg) / 2
        mk = (self.theta_k_max_deg + self.theta_k_min_deg) / 2
        ph = w * t + self.alpha_rad
        pk = w * t + self.phi_rad + self.alpha_rad
        return (ah * np.sin(ph) + mh, ak * np.sin(pk) + mk,
                ah * w * np.cos(ph), ak * w * np.cos(pk),
                -ah * w * w * np.sin(ph), -ak * w * w * np.sin(pk))

    def motion(self, t_s: np.ndarray, flow_speed_mps: float) -> LegMotion:
        """A one-row :class:`LegMotion` sampled at the uniform times ``t_s``."""
        th, tk, wh, wk, ah, ak = self.evaluate(t_s)
        dt = float(t_s[1] - t_s[0]) if len(t_s) > 1 else 1.0
        return LegMotion.from_arrays(dt, th, tk, wh, wk, np.full_like(th, flow_speed_mps), ah, ak)


@dataclass(frozen=True)
class RunMotion:
    """One run of a processed tunnel dataset as model input plus the measured wrench."""

    campaign_id: str
    run_id: str
    flow_speed_mps: float
    params: Mapping[str, float]
    interpolated: bool
    time_s: np.ndarray
    motion: LegMotion
    #: measured wrench (T, 6), contract channel order
    wrench: np.ndarray


def runs_from_frame(frame, params: tuple[str, ...] | None = None) -> list[RunMotion]:
    """Split a processed tunnel frame (contract section 3) into runs, in first-appearance order.

    ``dt_s`` of each run is the median tick interval of its ``time_s``.
    """
    import polars as pl

    from workbench.contract.columns import TUNNEL_MOTION_PARAMS, WRENCH_CHANNELS

    params = params or tuple(p for p in TUNNEL_MOTION_PARAMS if p in frame.columns)
    keys = ["campaign_id", "run_id"] if "campaign_id" in frame.columns else ["run_id"]
    out: list[RunMotion] = []
    for key, g in frame.group_by(keys, maintain_order=True):
        g = g.sort("time_s")
        t = g["time_s"].to_numpy()
        dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
        motion = LegMotion.from_arrays(dt, g["theta_h_deg"].to_numpy(), g["theta_k_deg"].to_numpy(),
                                       g["omega_h_dps"].to_numpy(), g["omega_k_dps"].to_numpy(),
                                       g["flow_speed_mps"].to_numpy())
        wrench = g.select(list(WRENCH_CHANNELS)).to_numpy()
        interp = bool(g["interpolated"][0]) if "interpolated" in g.columns else False
        out.append(RunMotion(
            campaign_id=str(key[0]) if len(keys) == 2 else "",
            run_id=str(key[-1]), flow_speed_mps=float(g["flow_speed_mps"][0]),
            params={p: float(g[p][0]) for p in params}, interpolated=interp, time_s=t,
            motion=motion, wrench=wrench,
        ))
    del pl
    return out
