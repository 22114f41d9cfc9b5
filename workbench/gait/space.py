"""The decision variables of gait optimisation (paper Table II) and their mapping to gaits.

A decision vector is ``[theta_h_min_deg, theta_k_max_deg, frequency_hz, alpha_LF, alpha_RF,
alpha_LH, alpha_RH]``: one joint range and frequency for all four legs (as in the paper) and a
phase per leg; theta_h_max, theta_k_min and phi are fixed (paper: -100 deg, 80 deg, pi/3).
The front legs' HAA angle (30 deg) is a robot constant (pipelines/robot.yaml), not a variable.

In that space every leg sweeps the same stroke and only the phases differ, so the mean yaw
torque of a gait cancels to first order between left and right legs and a gait turns only
through second-order effects (docs/gaits.md, "What the paper's gait space can do"). Named
extensions (``space.extension``) add variables and stay within what the gait and controller
files carry (per-leg joint ranges):

* ``paper`` (default): the paper's space above, 7 variables;
* ``per_side_range``: the joint ranges per side, ``[theta_h_min_left_deg, theta_h_min_right_deg,
  theta_k_max_left_deg, theta_k_max_right_deg, frequency_hz, alpha_LF, alpha_RF, alpha_LH,
  alpha_RH]``, 9 variables (left legs LF, LH; right legs RF, RH): a larger stroke on one side
  makes a net yaw torque, as a rower pulls harder on one oar.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from workbench.errors import SettingError
from workbench.hydro.robot import LEG_NAMES
from workbench.hydro.simulator import PHI_RAD, THETA_H_MAX_DEG, THETA_K_MIN_DEG, GaitBatch

#: decision-vector entries of the paper's space, in order
VARIABLES = ("theta_h_min_deg", "theta_k_max_deg", "frequency_hz") + tuple(f"alpha_{n.lower()}_rad" for n in LEG_NAMES)
#: named gait-space extensions -> their decision-vector entries
EXTENSIONS = {
    "paper": VARIABLES,
    "per_side_range": ("theta_h_min_left_deg", "theta_h_min_right_deg", "theta_k_max_left_deg",
                       "theta_k_max_right_deg", "frequency_hz") + VARIABLES[3:],
}
#: per leg (LF, RF, LH, RH): its side's column in the per-side variables (0 left, 1 right)
_SIDE = np.array([0, 1, 0, 1])


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
    #: ``paper`` or a named extension of :data:`EXTENSIONS` (the bounds above apply per side too)
    extension: str = "paper"

    def __post_init__(self):
        if self.extension not in EXTENSIONS:
            raise SettingError(f"space.extension must be one of {sorted(EXTENSIONS)}, got {self.extension!r}")
        for name in ("theta_h_min_deg", "theta_k_max_deg", "frequency_hz", "alpha_rad"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise SettingError(f"space.{name}: lower bound {lo} must be below upper bound {hi}")
        if self.frequency_hz[0] <= 0:
            raise SettingError("space.frequency_hz must be positive")

    @property
    def variables(self) -> tuple[str, ...]:
        """The decision-vector entries of this space, in order."""
        return EXTENSIONS[self.extension]

    def _bounds(self, k: int) -> np.ndarray:
        ranges = (self.theta_h_min_deg, self.theta_k_max_deg, self.frequency_hz)
        if self.extension == "per_side_range":
            ranges = (self.theta_h_min_deg, self.theta_h_min_deg, self.theta_k_max_deg, self.theta_k_max_deg,
                      self.frequency_hz)
        return np.array([r[k] for r in ranges] + [self.alpha_rad[k]] * 4)

    @property
    def xl(self) -> np.ndarray:
        """Lower bounds (n_var,)."""
        return self._bounds(0)

    @property
    def xu(self) -> np.ndarray:
        """Upper bounds (n_var,)."""
        return self._bounds(1)

    def gaits(self, x: np.ndarray) -> GaitBatch:
        """Decision vectors (B, n_var) -> gaits (phases wrapped into [0, 2 pi))."""
        x = np.atleast_2d(np.asarray(x, float))
        if x.shape[1] != len(self.variables):
            raise SettingError(f"decision vectors of space.extension {self.extension!r} need {len(self.variables)} "
                               f"entries {self.variables}, got {x.shape[1]}",
                               hint="vectors from a run with another space.extension belong to that space")
        if self.extension == "per_side_range":
            th, tk, f = x[:, 0:2][:, _SIDE], x[:, 2:4][:, _SIDE], x[:, 4]
        else:
            th, tk, f = x[:, 0], x[:, 1], x[:, 2]
        return GaitBatch.from_arrays(th, tk, f, np.mod(x[:, -4:], 2 * math.pi),
                                     theta_h_max_deg=self.theta_h_max_deg, theta_k_min_deg=self.theta_k_min_deg,
                                     phi_rad=self.phi_rad)

    def vectors(self, gaits: GaitBatch) -> np.ndarray:
        """Gaits -> decision vectors (B, n_var); refused when the gaits leave this space."""
        if self.extension == "per_side_range":
            cols = []
            for name in ("theta_h_min_deg", "theta_k_max_deg"):
                arr = getattr(gaits, name)
                if not (np.all(arr[:, 0] == arr[:, 2]) and np.all(arr[:, 1] == arr[:, 3])):
                    raise SettingError(f"{name} differs between legs of one side; per_side_range has one per side")
                cols += [arr[:, 0], arr[:, 1]]
            return np.column_stack(cols + [gaits.frequency_hz, gaits.alpha_rad])
        for name in ("theta_h_min_deg", "theta_k_max_deg"):
            arr = getattr(gaits, name)
            if not np.all(arr == arr[:, :1]):
                raise SettingError(f"{name} differs between legs; the decision vector has one value for all legs")
        return np.column_stack([gaits.theta_h_min_deg[:, 0], gaits.theta_k_max_deg[:, 0], gaits.frequency_hz,
                                gaits.alpha_rad])

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` decision vectors drawn uniformly within the bounds."""
        return self.xl + rng.random((n, len(self.variables))) * (self.xu - self.xl)
