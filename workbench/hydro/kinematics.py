"""Four-bar leg kinematics of the paper (section III-A-1): web midpoint Q, its rates, the web normal.

Conventions (drawn in docs/conventions.md, figure docs/figures/leg_conventions.png):

* Leg plane: X forward (the load cell's and robot's +y), Y up (the load cell's +z), origin at
  the hip axis O (the load cell's origin). The load cell's +x is the hip axis, out of the plane.
* ``theta_h``: angle of the thigh OC from +X, counter-clockwise (-90 deg hangs straight down).
* ``theta_k``: knee angle *relative to the thigh*: the knee servo's crank OA sits at
  ``psi = theta_h + theta_k + 90 deg``. Over the paper's ranges (theta_h in [-100, 10],
  theta_k in [-80, 80]) the thigh-crank angle stays within [10, 170] deg, so the linkage is
  never singular. theta_k = 80 deg is a nearly straight leg, -80 deg fully folded.
* OA = BC = 0.035 m, OC = AB = 0.125 m. B is the intersection of the circles about A (radius AB)
  and C (radius BC) on the far side of line AC from O: the assembled parallelogram,
  B = A + C (the paper's "larger Y" in the frame of line AC; in a fixed frame the literal
  rule switches branches inside the workspace, see the docs).
* Q lies on the calf line from B through C with BQ = 2.5 BC. The web lies along the calf; its
  normal ``n`` is the calf direction turned +90 deg in the leg plane.

Everything is vectorised over arbitrary array shapes; rates are analytic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LegGeometry:
    """Link lengths and web placement (SI)."""

    oa_m: float = 0.035
    oc_m: float = 0.125
    bq_over_bc: float = 2.5
    #: lateral (load-cell x) offset of the web's midplane from the hip axis origin
    web_offset_x_m: float = 0.02
    web_side_m: float = 0.06

    @property
    def bc_m(self) -> float:
        """BC = OA (parallelogram)."""
        return self.oa_m

    @property
    def ab_m(self) -> float:
        """AB = OC (parallelogram)."""
        return self.oc_m


DEFAULT_GEOMETRY = LegGeometry()


@dataclass(frozen=True)
class LegState:
    """Leg-plane kinematic state; arrays have shape ``(..., 2)`` (X forward, Y up) unless noted."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    q: np.ndarray
    q_vel: np.ndarray
    q_acc: np.ndarray
    normal: np.ndarray
    tangent: np.ndarray
    #: web angular velocity (rad/s), shape ``(...)``
    web_rate: np.ndarray

    def to_loadcell(self, vec2: np.ndarray, x: float | np.ndarray = 0.0) -> np.ndarray:
        """Map a leg-plane vector ``(..., 2)`` to load-cell coordinates ``(..., 3)`` = (x, X, Y)."""
        vec2 = np.asarray(vec2)
        xs = np.broadcast_to(np.asarray(x, dtype=float), vec2.shape[:-1])
        return np.stack([xs, vec2[..., 0], vec2[..., 1]], axis=-1)


def _unit(angle: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(angle), np.sin(angle)], axis=-1)


def _perp(angle: np.ndarray) -> np.ndarray:
    return np.stack([-np.sin(angle), np.cos(angle)], axis=-1)


def leg_state(
    theta_h_rad: np.ndarray,
    theta_k_rad: np.ndarray,
    omega_h_rps: np.ndarray | float = 0.0,
    omega_k_rps: np.ndarray | float = 0.0,
    alpha_h_rps2: np.ndarray | float = 0.0,
    alpha_k_rps2: np.ndarray | float = 0.0,
    geometry: LegGeometry = DEFAULT_GEOMETRY,
) -> LegState:
    """Positions of A, B, C, Q and Q's analytic velocity and acceleration from joint angles and rates."""
    th, tk = np.broadcast_arrays(np.asarray(theta_h_rad, float), np.asarray(theta_k_rad, float))
    wh = np.broadcast_to(np.asarray(omega_h_rps, float), th.shape)
    wk = np.broadcast_to(np.asarray(omega_k_rps, float), th.shape)
    ah = np.broadcast_to(np.asarray(alpha_h_rps2, float), th.shape)
    ak = np.broadcast_to(np.asarray(alpha_k_rps2, float), th.shape)
    psi = th + tk + np.pi / 2
    wpsi = wh + wk
    apsi = ah + ak
    uc, pc = _unit(th), _perp(th)
    ua, pa = _unit(psi), _perp(psi)
    c = geometry.oc_m * uc
    a = geometry.oa_m * ua
    b = a + c
    # Q = B + r (C - B) with C - B = -A  =>  Q = C + (1 - r) A
    k = 1.0 - geometry.bq_over_bc
    q = c + k * a
    c_vel = geometry.oc_m * wh[..., None] * pc
    a_vel = geometry.oa_m * wpsi[..., None] * pa
    c_acc = geometry.oc_m * (ah[..., None] * pc - (wh**2)[..., None] * uc)
    a_acc = geometry.oa_m * (apsi[..., None] * pa - (wpsi**2)[..., None] * ua)
    # calf direction B->C->Q is -ua; the web normal is that turned +90 deg
    tangent = -ua
    normal = -pa
    return LegState(a=a, b=b, c=c, q=q, q_vel=c_vel + k * a_vel, q_acc=c_acc + k * a_acc,
                    normal=normal, tangent=tangent, web_rate=np.array(wpsi))
