"""The paper's empirical formula (EF, section III-A-2): added mass, drag and web inertia on the web normal.

F_n = -(2 pi rho a^3 + m_web) a_n + 0.5 rho S C_R |V_n| V_n, along the web normal n, where
a_n is the normal component of Q's acceleration and V_n the normal component of the water's
velocity relative to Q (the tunnel flow runs along the load cell's -y). The force acts at Q,
which sits ``web_offset_x_m`` off the hip axis, so the EF also predicts torques; it has no
fx, no tangential force, no link drag, no weight or buoyancy and no memory.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from workbench.hydro.kinematics import DEFAULT_GEOMETRY, LegGeometry, leg_state
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.motion import LegMotion


@dataclass(frozen=True)
class EFParams:
    """EF constants (paper values)."""

    rho_kgpm3: float = 1000.0
    a_m: float = 0.03          # characteristic length, half the web side
    c_r: float = 0.7           # drag coefficient
    m_web_kg: float = 0.010    # web mass
    added_mass_factor: float = 2 * np.pi  # m_a = factor * rho * a^3

    @property
    def area_m2(self) -> float:
        """S = (2a)^2."""
        return (2 * self.a_m) ** 2

    @property
    def added_mass_kg(self) -> float:
        """2 pi rho a^3 (about 0.17 kg)."""
        return self.added_mass_factor * self.rho_kgpm3 * self.a_m**3


def web_normal_force_to_wrench(f_n: np.ndarray, state, geometry: LegGeometry) -> np.ndarray:
    """A force ``f_n`` (..., ) along the web normal applied at Q -> load-cell wrench (..., 6)."""
    force2 = f_n[..., None] * state.normal
    return force_at_point_to_wrench(force2, state.q, geometry.web_offset_x_m)


def force_at_point_to_wrench(force2: np.ndarray, point2: np.ndarray, x_m: float | np.ndarray) -> np.ndarray:
    """A leg-plane force (..., 2) applied at a leg-plane point (..., 2) offset ``x_m`` -> wrench (..., 6)."""
    zeros = np.zeros(force2.shape[:-1])
    f3 = np.stack([zeros, force2[..., 0], force2[..., 1]], axis=-1)
    r3 = np.stack([np.broadcast_to(np.asarray(x_m, float), zeros.shape), point2[..., 0], point2[..., 1]], axis=-1)
    return np.concatenate([f3, np.cross(r3, f3)], axis=-1)


class EmpiricalFormula(LegForceModel):
    """The paper's EF as a leg force model."""

    name = "ef"

    def __init__(self, params: EFParams | None = None, geometry: LegGeometry = DEFAULT_GEOMETRY):
        self.params = params or EFParams()
        self.geometry = geometry

    def normal_force(self, motion: LegMotion) -> tuple[np.ndarray, object]:
        """EF normal force (B, T) and the kinematic state it was computed on."""
        p = self.params
        ah, ak = motion.accelerations_dps2()
        st = leg_state(np.radians(motion.theta_h_deg), np.radians(motion.theta_k_deg),
                       np.radians(motion.omega_h_dps), np.radians(motion.omega_k_dps),
                       np.radians(ah), np.radians(ak), self.geometry)
        a_n = np.einsum("...i,...i->...", st.q_acc, st.normal)
        water = np.zeros_like(st.q_vel)
        water[..., 0] = -motion.flow_speed_mps
        v_n = np.einsum("...i,...i->...", water - st.q_vel, st.normal)
        f_n = -(p.added_mass_kg + p.m_web_kg) * a_n + 0.5 * p.rho_kgpm3 * p.area_m2 * p.c_r * np.abs(v_n) * v_n
        return f_n, st

    def wrench(self, motion: LegMotion) -> np.ndarray:
        """EF wrench (B, T, 6) in the load cell's frame."""
        f_n, st = self.normal_force(motion)
        return web_normal_force_to_wrench(f_n, st, self.geometry)

    def flow_provider(self, motion: LegMotion):
        """``flow (B, T) -> wrench (B, T, 6)`` for this joint motion, the kinematics computed once.

        Same numbers as :meth:`wrench` with ``flow_speed_mps`` replaced; the full-body simulator
        calls it once per fixed-point iteration on the flow history.
        """
        p = self.params
        ah, ak = motion.accelerations_dps2()
        st = leg_state(np.radians(motion.theta_h_deg), np.radians(motion.theta_k_deg),
                       np.radians(motion.omega_h_dps), np.radians(motion.omega_k_dps),
                       np.radians(ah), np.radians(ak), self.geometry)
        inertial = -(p.added_mass_kg + p.m_web_kg) * np.einsum("...i,...i->...", st.q_acc, st.normal)
        qv_n = np.einsum("...i,...i->...", st.q_vel, st.normal)
        n_x = st.normal[..., 0]
        unit = web_normal_force_to_wrench(np.ones_like(n_x), st, self.geometry)
        k = 0.5 * p.rho_kgpm3 * p.area_m2 * p.c_r

        def wrench(flow_speed_mps: np.ndarray, legs: np.ndarray | None = None, lo: int = 0,
                   hi: int | None = None) -> np.ndarray:
            flow = np.asarray(flow_speed_mps, float)
            if legs is None and lo == 0 and hi is None:
                v_n = -flow * n_x - qv_n
                return (inertial + k * np.abs(v_n) * v_n)[..., None] * unit
            # some legs over some ticks (the simulator's windows): the same numbers, elementwise
            at = (slice(None) if legs is None else np.asarray(legs), slice(lo, hi))
            v_n = -flow[at] * n_x[at] - qv_n[at]
            return (inertial[at] + k * np.abs(v_n) * v_n)[..., None] * unit[at]

        wrench.partial = True  # legs and ticks on request (workbench.hydro.simulator.leg_wrench_provider)
        return wrench

    def describe(self) -> dict:
        """EF constants."""
        return {"name": self.name, **asdict(self.params), "added_mass_kg": self.params.added_mass_kg}
