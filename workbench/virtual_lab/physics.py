"""The virtual tunnel's ground truth: the wrench a paddling leg puts on the load cell.

``TrueLegModel(truth="rich")`` is deliberately richer than the paper's EF (field notes,
"The rig in numbers"), with every term in the load cell's frame and contract channel order:

* web normal force from a normal-force coefficient, ``0.5 rho L C_N90 |V| V_n`` per unit chord
  (``C_N = C_N90 sin(alpha)``, ``C_N90 = 1.17``), integrated over the chord so that the web's
  rotation moves the centre of pressure, plus a small tangential friction;
* a circulatory lag on that force: two-state Wagner/Jones (default) or first order, with time
  constants that scale with ``c / max(|V_rel|, floor)``;
* flat-plate added mass ``rho 0.579 (pi/4) L^3`` (DNV RP-C205, about 98 g; optional KC growth)
  on the rate of change of the web's normal velocity relative to the water, ``d/dt (v_rel . n)
  = a_rel . n + omega v_t`` (the rotating-plate term: the normal turns at the web's rate omega,
  so the tangential relative velocity feeds the normal one), and the web's added moment of inertia;
* thigh and calf as cylinders (Morison: cross-flow drag and added mass, integrated along the
  links O-C and B-web), web and link structural inertia;
* weight and buoyancy of thigh, calf and web at their own centres (a small net fz and a
  pose-dependent tx), and a small lateral force (fx) from the finite web's spanwise flow.

``truth="ef"`` is exactly :class:`~workbench.hydro.ef.EmpiricalFormula`. In both modes planted
effect terms (``extra_*``, ``lift_cl``, ``series_lag_tau_chords``, ``point_loads``) follow the
canonical effect definitions of the briefing's table; docs/virtual-lab.md gives the equations.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Literal

import numpy as np

from workbench.errors import ModelError
from workbench.hydro.ef import EFParams, EmpiricalFormula, force_at_point_to_wrench
from workbench.hydro.kinematics import DEFAULT_GEOMETRY, LegGeometry, leg_state
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.motion import LegMotion

TRUTHS = ("rich", "ef")
LAGS = ("wagner", "first_order", "none")


@dataclass(frozen=True)
class TruthSettings:
    """Physical constants of the ground truth (SI). Defaults: field notes and docs/virtual-lab.md.

    The ``physics`` block of pipelines/virtual_lab.yaml's ``tunnel`` section, built by
    :func:`workbench.params.build` (unknown keys, wrong types and an unknown ``lag`` are a ParamsError).
    """

    rho_kgpm3: float = 1000.0
    gravity_mps2: float = 9.81
    # web: normal force C_N = C_N90 sin(alpha), tangential friction, spanwise (lateral) force
    c_n90: float = 1.17
    c_t: float = 0.03
    lateral_fraction: float = 0.03
    web_quadrature: int = 5
    # web added mass (DNV flat plate) with optional Keulegan-Carpenter growth, web mass/volume
    added_mass_coeff: float = 0.579
    kc_gain: float = 0.25
    #: the rotating-plate term of the added-mass force: m_a omega v_t beside m_a a_n (False: a_n only)
    rotating_added_mass: bool = True
    web_mass_kg: float = 0.010
    web_volume_m3: float = 1.08e-5
    # circulatory lag of the normal force
    lag: Literal["wagner", "first_order", "none"] = "wagner"
    circulatory_fraction: float = 1.0
    lag_tau_chords: float = 1.5
    wagner_amplitudes: tuple[float, float] = (0.165, 0.335)
    wagner_rates: tuple[float, float] = (0.0455, 0.3)
    speed_floor_mps: float = 0.05
    # thigh (O-C) and calf (B to the web's near edge) as cylinders
    link_cd_d_m: float = 0.005
    link_diameter_m: float = 0.006
    link_added_mass_coeff: float = 1.0
    link_x_m: float = 0.01
    thigh_mass_kg: float = 0.020
    thigh_volume_m3: float = 1.85e-5
    calf_mass_kg: float = 0.012
    calf_volume_m3: float = 1.1e-5
    link_quadrature: int = 4
    # planted effect terms (canonical definitions; zero = absent)
    extra_added_mass_kg: float = 0.0
    extra_normal_drag_c: float = 0.0
    extra_link_cd_d_m: float = 0.0
    lift_cl: float = 0.0
    series_lag_tau_chords: float = 0.0
    point_loads: tuple[tuple[float, float], ...] = ()

    def web_added_mass_kg(self, side_m: float) -> float:
        """Flat-plate added mass rho 0.579 (pi/4) L^3 (about 98 g for L = 0.06 m)."""
        return self.rho_kgpm3 * self.added_mass_coeff * np.pi / 4 * side_m**3


#: the name before issue 17 (settings classes end in ``Settings``); kept for existing imports
TruthParams = TruthSettings


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1]


def _perp(v: np.ndarray) -> np.ndarray:
    """Turn a leg-plane vector +90 degrees."""
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def _couple_x(m: np.ndarray) -> np.ndarray:
    """A pure in-plane couple (about the load cell's +x) as a wrench (..., 6)."""
    out = np.zeros(m.shape + (6,))
    out[..., 3] = m
    return out


def _lateral_force_wrench(fx: np.ndarray, point2: np.ndarray) -> np.ndarray:
    """A force along the load cell's +x applied at a leg-plane point -> wrench; r x F = (0, z fx, -y fx)."""
    out = np.zeros(fx.shape + (6,))
    out[..., 0] = fx
    out[..., 4] = point2[..., 1] * fx
    out[..., 5] = -point2[..., 0] * fx
    return out


def first_order_lag(u: np.ndarray, rate_per_s: np.ndarray, dt_s: float) -> np.ndarray:
    """Integrate ``dx/dt = rate (u - x)`` along axis 1 of ``u`` (B, T, ...), starting at ``x = u[:, 0]``.

    The rate may change every step (time constants that scale with c/|V|); each step is the
    exact exponential update for the mid-step input, so large ``rate * dt`` stays stable.
    """
    gain = -np.expm1(-np.asarray(rate_per_s, float) * dt_s)  # (B, T)
    extra = u.ndim - 2
    gain = gain.reshape(gain.shape + (1,) * extra)
    out = np.empty_like(u)
    x = u[:, 0].copy()
    out[:, 0] = x
    for k in range(1, u.shape[1]):
        u_mid = 0.5 * (u[:, k - 1] + u[:, k])
        x += gain[:, k] * (u_mid - x)
        out[:, k] = x
    return out


class TrueLegModel(LegForceModel):
    """Ground-truth leg force model of the virtual tunnel (``truth="rich"``) or the EF (``truth="ef"``)."""

    name = "truth"

    def __init__(self, truth: str = "rich", params: TruthSettings | None = None,
                 geometry: LegGeometry = DEFAULT_GEOMETRY, ef_params: EFParams | None = None):
        if truth not in TRUTHS:
            raise ModelError(f"unknown truth {truth!r}", hint=f"one of {TRUTHS}")
        self.truth = truth
        self.params = params or TruthSettings()
        if self.params.lag not in LAGS:
            raise ModelError(f"unknown circulatory lag {self.params.lag!r}", hint=f"one of {LAGS}")
        self.geometry = geometry
        self.ef_params = ef_params or EFParams()

    def with_params(self, **changes) -> "TrueLegModel":
        """A copy with some :class:`TruthSettings` fields changed (how force effects are planted)."""
        return TrueLegModel(self.truth, replace(self.params, **changes), self.geometry, self.ef_params)

    def describe(self) -> dict:
        """Truth mode, constants and geometry (JSON-serialisable)."""
        p = asdict(self.params)
        p["point_loads"] = [list(x) for x in self.params.point_loads]
        return {"name": self.name, "truth": self.truth, "params": p, "geometry": asdict(self.geometry),
                "web_added_mass_kg": self.params.web_added_mass_kg(self.geometry.web_side_m)}

    # ------------------------------------------------------------------ public
    def wrench(self, motion: LegMotion) -> np.ndarray:
        """Load-cell wrench (B, T, 6) for the motion batch (angles/rates in degrees, flow in m/s)."""
        k = self._kinematics(motion)
        if self.truth == "ef":
            out = self._ef(motion, k)
        else:
            out = self._rich(k)
        return out + self._planted(k)

    # ------------------------------------------------------------- internals
    def _kinematics(self, motion: LegMotion) -> dict:
        """Leg state, water velocity/acceleration and rigid-body rates of C and A (leg plane)."""
        ah, ak = motion.accelerations_dps2()
        th, tk = np.radians(motion.theta_h_deg), np.radians(motion.theta_k_deg)
        wh, wk = np.radians(motion.omega_h_dps), np.radians(motion.omega_k_dps)
        ah, ak = np.radians(ah), np.radians(ak)
        st = leg_state(th, tk, wh, wk, ah, ak, self.geometry)
        u = np.asarray(motion.flow_speed_mps, float)
        if u.shape[1] > 2 and np.ptp(u, axis=1).max() > 0:
            du = np.gradient(u, motion.dt_s, axis=1, edge_order=2)
        else:
            du = np.zeros_like(u)
        zero = np.zeros_like(u)
        water = np.stack([-u, zero], axis=-1)       # the tunnel flow runs along the load cell's -y
        water_acc = np.stack([-du, zero], axis=-1)
        wpsi, apsi = wh + wk, ah + ak
        c_vel = wh[..., None] * _perp(st.c)
        c_acc = ah[..., None] * _perp(st.c) - (wh**2)[..., None] * st.c
        a_vel = wpsi[..., None] * _perp(st.a)
        a_acc = apsi[..., None] * _perp(st.a) - (wpsi**2)[..., None] * st.a
        rel_q = water - st.q_vel
        return {"st": st, "dt": motion.dt_s, "water": water, "water_acc": water_acc,
                "c_vel": c_vel, "c_acc": c_acc, "a_vel": a_vel, "a_acc": a_acc, "web_acc": apsi,
                "rel_q": rel_q, "speed_q": np.hypot(rel_q[..., 0], rel_q[..., 1])}

    def _lag_rate(self, speed: np.ndarray, tau_chords: float) -> np.ndarray:
        """1/tau with tau = tau_chords * c / max(|V_rel|, floor)."""
        c = self.geometry.web_side_m
        return np.maximum(speed, self.params.speed_floor_mps) / (tau_chords * c)

    def _circulatory(self, u: np.ndarray, speed: np.ndarray, dt: float) -> np.ndarray:
        """The rich model's circulatory lag on the quasi-steady inputs u (B, T, K)."""
        p = self.params
        c = self.geometry.web_side_m
        frac = p.circulatory_fraction
        if p.lag == "none" or frac == 0:
            return u
        if p.lag == "first_order":
            lagged = first_order_lag(u, self._lag_rate(speed, p.lag_tau_chords), dt)
        else:
            # Jones' two-state Wagner approximation: phi(s) = 1 - A1 e^(-b1 s) - A2 e^(-b2 s), s = 2 V t / c
            v = np.maximum(speed, p.speed_floor_mps)
            lagged = (1.0 - sum(p.wagner_amplitudes)) * u
            for amp, b in zip(p.wagner_amplitudes, p.wagner_rates, strict=True):
                lagged = lagged + amp * first_order_lag(u, 2.0 * b * v / c, dt)
        return (1.0 - frac) * u + frac * lagged

    def _series_lag(self, u: np.ndarray, speed: np.ndarray, dt: float) -> np.ndarray:
        tau = self.params.series_lag_tau_chords
        return u if tau <= 0 else first_order_lag(u, self._lag_rate(speed, tau), dt)

    def _ef(self, motion: LegMotion, k: dict) -> np.ndarray:
        """Exactly the EF; with a planted circulatory lag, its drag term passes the lag."""
        if self.params.series_lag_tau_chords <= 0:
            return EmpiricalFormula(self.ef_params, self.geometry).wrench(motion)
        drag_only = replace(self.ef_params, added_mass_factor=0.0, m_web_kg=0.0)
        inertia_only = replace(self.ef_params, c_r=0.0)
        f_d, st = EmpiricalFormula(drag_only, self.geometry).normal_force(motion)
        f_i, _ = EmpiricalFormula(inertia_only, self.geometry).normal_force(motion)
        f_d = self._series_lag(f_d[..., None], k["speed_q"], k["dt"])[..., 0]
        return force_at_point_to_wrench((f_d + f_i)[..., None] * st.normal, st.q, self.geometry.web_offset_x_m)

    def _rich(self, k: dict) -> np.ndarray:
        p, g = self.params, self.geometry
        st, water = k["st"], k["water"]
        n, t = st.normal, st.tangent
        side = g.web_side_m
        # quasi-steady normal force and its moment about Q, integrated over the chord (span = side)
        xs, ws = np.polynomial.legendre.leggauss(p.web_quadrature)
        f_qs = np.zeros(n.shape[:-1])
        m_qs = np.zeros(n.shape[:-1])
        for x, w in zip(xs * side / 2, ws * side / 2, strict=True):
            rel = water - (st.q_vel + (st.web_rate * x)[..., None] * n)
            f = 0.5 * p.rho_kgpm3 * side * p.c_n90 * np.hypot(rel[..., 0], rel[..., 1]) * _dot(rel, n)
            f_qs += w * f
            m_qs += w * x * f
        lagged = self._circulatory(np.stack([f_qs, m_qs], axis=-1), k["speed_q"], k["dt"])
        lagged = self._series_lag(lagged, k["speed_q"], k["dt"])
        f_c, m_c = lagged[..., 0], lagged[..., 1]
        # added mass on the rate of change of the normal velocity relative to the water, with
        # optional KC growth: d/dt((v_Q - u) . n) = (a_Q - du/dt) . n + (v_Q - u) . dn/dt, and
        # dn/dt = -omega t (n = -(-sin psi, cos psi) turns at omega = d psi/dt), so the second
        # part is omega ((u - v_Q) . t) = omega v_t: the rotating-plate term
        v_t = _dot(k["rel_q"], t)
        rel_acc_n = _dot(st.q_acc - k["water_acc"], n)
        if p.rotating_added_mass:
            rel_acc_n = rel_acc_n + st.web_rate * v_t
        m_a = p.web_added_mass_kg(side) * self._kc_factor(k)
        i_a = p.rho_kgpm3 * np.pi * (side / 2) ** 4 / 8 * side  # 2-D strip: pi rho b^4 / 8 per span
        f_t = 0.5 * p.rho_kgpm3 * side**2 * p.c_t * np.abs(v_t) * v_t
        net_web = (p.rho_kgpm3 * p.web_volume_m3 - p.web_mass_kg) * p.gravity_mps2
        force = ((f_c - m_a * rel_acc_n)[..., None] * n + f_t[..., None] * t - p.web_mass_kg * st.q_acc)
        force[..., 1] += net_web
        out = force_at_point_to_wrench(force, st.q, g.web_offset_x_m)
        out += _couple_x(m_c - i_a * k["web_acc"])
        out += _lateral_force_wrench(p.lateral_fraction * f_c, st.q)
        out += self._links(k, p.link_cd_d_m, with_inertia=True)
        return out

    def _kc_factor(self, k: dict) -> np.ndarray | float:
        """1 + kc_gain KC^(2/3) per row, KC = 2 pi A / L with A half the diagonal of Q's path box.

        The bounding box of Q's path does not change when a run is padded with rest at its
        start pose, so the factor is a property of the run, not of the batch it is computed in.
        """
        gain = self.params.kc_gain
        if gain == 0:
            return 1.0
        q = k["st"].q
        amplitude = 0.5 * np.hypot(np.ptp(q[..., 0], axis=1), np.ptp(q[..., 1], axis=1))[:, None]
        kc = 2 * np.pi * amplitude / self.geometry.web_side_m
        return 1.0 + gain * kc ** (2.0 / 3.0)

    def _link_points(self, k: dict):
        """Quadrature points of thigh and calf: (position, velocity, acceleration, normal, weight, link)."""
        p, g, st = self.params, self.geometry, k["st"]
        xs, ws = np.polynomial.legendre.leggauss(p.link_quadrature)
        s01, w01 = (xs + 1) / 2, ws / 2
        thigh_len = g.oc_m
        e = st.c / thigh_len
        for s, w in zip(s01, w01, strict=True):  # thigh O -> C
            yield s * st.c, s * k["c_vel"], s * k["c_acc"], _perp(e), w * thigh_len, "thigh"
        # calf: points C + kappa A, from B (kappa = 1) to the web's near edge
        edge = g.bq_over_bc * g.bc_m - g.web_side_m / 2
        kappa_end = 1.0 - edge / g.oa_m
        for s, w in zip(s01, w01, strict=True):
            kap = 1.0 + s * (kappa_end - 1.0)
            yield (st.c + kap * st.a, k["c_vel"] + kap * k["a_vel"], k["c_acc"] + kap * k["a_acc"],
                   st.normal, w * edge, "calf")

    def _links(self, k: dict, cd_d_m: float, with_inertia: bool) -> np.ndarray:
        """Cross-flow drag (and, for the truth, added mass, inertia, weight) of thigh and calf."""
        p, g = self.params, self.geometry
        water, water_acc = k["water"], k["water_acc"]
        m_added = p.link_added_mass_coeff * p.rho_kgpm3 * np.pi * p.link_diameter_m**2 / 4  # per length
        lengths = {"thigh": g.oc_m, "calf": g.bq_over_bc * g.bc_m - g.web_side_m / 2}
        mass = {"thigh": p.thigh_mass_kg, "calf": p.calf_mass_kg}
        net = {"thigh": (p.rho_kgpm3 * p.thigh_volume_m3 - p.thigh_mass_kg) * p.gravity_mps2,
               "calf": (p.rho_kgpm3 * p.calf_volume_m3 - p.calf_mass_kg) * p.gravity_mps2}
        out = np.zeros(water.shape[:-1] + (6,))
        for pos, vel, acc, nrm, dl, link in self._link_points(k):
            v_n = _dot(water - vel, nrm)
            f_n = 0.5 * p.rho_kgpm3 * cd_d_m * np.abs(v_n) * v_n * dl
            force = f_n[..., None] * nrm
            if with_inertia:
                force = force - (m_added * dl * _dot(acc - water_acc, nrm))[..., None] * nrm
                force = force - (mass[link] / lengths[link] * dl) * acc
                force[..., 1] += net[link] / lengths[link] * dl
            out += force_at_point_to_wrench(force, pos, p.link_x_m)
        return out

    def _planted(self, k: dict) -> np.ndarray:
        """Planted effect terms on top of either truth (canonical definitions)."""
        p, g, st = self.params, self.geometry, k["st"]
        out = np.zeros(st.q.shape[:-1] + (6,))
        f_n = np.zeros(st.q.shape[:-1])
        area = g.web_side_m**2
        if p.extra_added_mass_kg:
            f_n -= p.extra_added_mass_kg * _dot(st.q_acc, st.normal)
        v_n = _dot(k["rel_q"], st.normal)
        if p.extra_normal_drag_c:
            f_n += 0.5 * p.rho_kgpm3 * area * p.extra_normal_drag_c * np.abs(v_n) * v_n
        if p.lift_cl:
            f_n += 0.5 * p.rho_kgpm3 * area * p.lift_cl * k["speed_q"] * _dot(k["rel_q"], st.tangent)
        if p.extra_normal_drag_c or p.extra_added_mass_kg or p.lift_cl:
            out += force_at_point_to_wrench(f_n[..., None] * st.normal, st.q, g.web_offset_x_m)
        if p.extra_link_cd_d_m:
            out += self._links(k, p.extra_link_cd_d_m, with_inertia=False)
        for net_n, arm_m in p.point_loads:
            # vertical force at arm_m from the hip along the (3-D) hip-to-Q line
            q3 = np.concatenate([np.full(st.q.shape[:-1] + (1,), g.web_offset_x_m), st.q], axis=-1)
            point = arm_m * q3 / np.linalg.norm(q3, axis=-1, keepdims=True)
            fz = np.full(st.q.shape[:-1], float(net_n))
            out[..., 2] += fz
            out[..., 3] += point[..., 1] * fz
            out[..., 4] -= point[..., 0] * fz
        return out
