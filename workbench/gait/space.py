"""The decision variables of gait optimisation (paper Table II) and their mapping to gaits.

A decision vector is ``[theta_h_min_deg, theta_k_max_deg, frequency_hz, alpha_LF, alpha_RF,
alpha_LH, alpha_RH]``: one joint range and frequency for all four legs (as in the paper) and a
phase per leg; theta_h_max, theta_k_min and phi are fixed (paper: -100 deg, 80 deg, pi/3).
The front legs' HAA angle (30 deg) is a robot constant (pipelines/robot.yaml), not a variable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from workbench.hydro.robot import LEG_NAMES
from workbench.hydro.simulator import PHI_RAD, THETA_H_MAX_DEG, THETA_K_MIN_DEG, GaitBatch

#: decision-vector entries, in order
VARIABLES = ("theta_h_min_deg", "theta_k_max_deg", "frequency_hz") + tuple(f"alpha_{n.lower()}_rad" for n in LEG_NAMES)


@dataclass(frozen=True)
class GaitSpace:
    """Bounds of the decision variables and the fixed gait constants (``space`` in pipelines/gait.yaml)."""

    theta_h_min_deg: tuple[float, float] = (-50.0, 10.0)
    theta_k_max_deg: tuple[float, float] = (-80.0, -20.0)
    frequency_hz: tuple[float, float] = (0.2, 0.65)
    alpha_rad: tuple[float, float] = (0.0, 2 * math.pi)
    theta_h_max_deg: float = THETA_H_MAX_DEG
    theta_k_min_deg: float = THETA_K_MIN_DEG
    phi_rad: float = PHI_RAD

    def __post_init__(self):
        for name in ("theta_h_min_deg", "theta_k_max_deg", "frequency_hz", "alpha_rad"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise ValueError(f"space.{name}: lower bound {lo} must be below upper bound {hi}")
        if self.frequency_hz[0] <= 0:
            raise ValueError("space.frequency_hz must be positive")

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any] | None) -> "GaitSpace":
        """From the parameter file's ``space`` section (unknown keys refused)."""
        doc = dict(doc or {})
        unknown = sorted(set(doc) - set(cls.__dataclass_fields__))
        if unknown:
            raise ValueError(f"unknown space setting(s) {unknown}")
        kw: dict[str, Any] = {}
        for k, v in doc.items():
            if k.endswith(("_deg", "_hz", "_rad")) and isinstance(v, (list, tuple)):
                kw[k] = (float(v[0]), float(v[1]))
            else:
                kw[k] = float(v)
        return cls(**kw)

    @property
    def xl(self) -> np.ndarray:
        """Lower bounds (7,)."""
        return np.array([self.theta_h_min_deg[0], self.theta_k_max_deg[0], self.frequency_hz[0]]
                        + [self.alpha_rad[0]] * 4)

    @property
    def xu(self) -> np.ndarray:
        """Upper bounds (7,)."""
        return np.array([self.theta_h_min_deg[1], self.theta_k_max_deg[1], self.frequency_hz[1]]
                        + [self.alpha_rad[1]] * 4)

    def gaits(self, x: np.ndarray) -> GaitBatch:
        """Decision vectors (B, 7) -> gaits (phases wrapped into [0, 2 pi))."""
        x = np.atleast_2d(np.asarray(x, float))
        if x.shape[1] != len(VARIABLES):
            raise ValueError(f"decision vectors need {len(VARIABLES)} entries {VARIABLES}, got {x.shape[1]}")
        return GaitBatch.from_arrays(x[:, 0], x[:, 1], x[:, 2], np.mod(x[:, 3:7], 2 * math.pi),
                                     theta_h_max_deg=self.theta_h_max_deg, theta_k_min_deg=self.theta_k_min_deg,
                                     phi_rad=self.phi_rad)

    def vectors(self, gaits: GaitBatch) -> np.ndarray:
        """Gaits (one joint range per gait) -> decision vectors (B, 7)."""
        for name in ("theta_h_min_deg", "theta_k_max_deg"):
            arr = getattr(gaits, name)
            if not np.all(arr == arr[:, :1]):
                raise ValueError(f"{name} differs between legs; the decision vector has one value for all legs")
        return np.column_stack([gaits.theta_h_min_deg[:, 0], gaits.theta_k_max_deg[:, 0], gaits.frequency_hz,
                                gaits.alpha_rad])

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` decision vectors drawn uniformly within the bounds."""
        return self.xl + rng.random((n, len(VARIABLES))) * (self.xu - self.xl)
