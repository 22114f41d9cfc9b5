"""The force effects that cover what the EF lacks, recovered from a campaign planted by the test's own formulas.

The campaign is the EF plus every planted load, written here from first principles on a fine
time grid (650 Hz, decimated to the 65 Hz ticks): positions from the joint angles only, every
velocity and acceleration by finite differences, the chord integral by a 24-point midpoint rule,
the lags by exponential steps of a 10x finer grid, link loads by a 24-point midpoint rule. None
of the library's own kinematics or columns produce these data.
"""

import numpy as np
import polars as pl
import pytest

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose.chain import Active, Configuration
from workbench.diagnose.data import DataSettings, prepare
from workbench.diagnose.effects.fluid import (
    AddedMassError,
    AddedMassKC,
    DragCoefficientError,
    LateralForce,
    LinkInertia,
    LinkWeightBuoyancy,
    NormalForceLaw,
    RotatingAddedMass,
    TangentialFriction,
    WagnerLag,
    WebAddedInertia,
)
from workbench.diagnose.problem import FitSettings, Problem
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.kinematics import DEFAULT_GEOMETRY as G
from workbench.hydro.kinematics import leg_state
from workbench.hydro.motion import JointSinusoid, LegMotion

RHO, L = 1000.0, G.web_side_m
FINE = 10                      # fine samples per 65 Hz tick
PLANT = {"normal_force_law.c_n90": 0.5, "wagner_lag.a_slow": 0.2, "wagner_lag.a_fast": 0.4,
         "rotating_added_mass.m_a_kg": 0.1, "added_mass_kc.m_kc_kg": 0.03, "link_inertia.m_kgpm": 0.25,
         "link_inertia.web_t_kg": 0.012, "lateral_force.c_lat": 0.04,
         "lateral_force.c_lat_slow": 0.012, "lateral_force.c_lat_fast": 0.02,
         "tangential_friction.c_t": 0.03, "web_added_inertia.i_kgm2": 2e-5, "link_weight_buoyancy.net_thigh_n": -0.03,
         "link_weight_buoyancy.net_calf_n": -0.02, "link_weight_buoyancy.net_web_n": 0.015}
SETS = [(10.0, -20.0, 0.3, 1.0), (-10.0, -40.0, 0.4, 2.1), (-30.0, -60.0, 0.5, 3.1), (-50.0, -80.0, 0.6, 4.2),
        (10.0, -60.0, 0.6, 5.2), (-30.0, -20.0, 0.3, 2.1), (-10.0, -80.0, 0.5, 1.0), (-50.0, -40.0, 0.4, 3.1),
        (10.0, -40.0, 0.5, 4.2), (-30.0, -80.0, 0.4, 5.2)]
SPEEDS = (0.0, 0.12, 0.25)


def _point_wrench(fx_leg, fy_leg, px, py, x_off):
    """Load-cell wrench of a leg-plane force at a leg-plane point x_off off the hip axis (r x F)."""
    return np.stack([0 * fx_leg, fx_leg, fy_leg, px * fy_leg - py * fx_leg, -x_off * fy_leg, x_off * fx_leg], -1)


def _lag(u, rate, dt):
    """dx/dt = rate (u - x) by exponential steps on a 10x finer linearly interpolated grid."""
    n = len(u)
    tf = np.arange((n - 1) * 10 + 1) / 10.0
    uf = np.interp(tf, np.arange(n), u)
    rf = np.interp(tf, np.arange(n), rate)
    x = np.empty_like(uf)
    x[0] = uf[0]
    e = np.exp(-rf * dt / 10)
    for k in range(1, len(uf)):
        x[k] = uf[k] + e[k] * (x[k - 1] - uf[k])
    return x[::10]


def _planted(params, flow, t):
    """The planted loads (load-cell wrench) on the fine grid ``t``."""
    js = JointSinusoid.from_params(params)
    th, tk = (np.radians(a) for a in js.evaluate(t)[:2])
    dt = t[1] - t[0]
    st = leg_state(th, tk, geometry=G)
    q, c, a = st.q, st.c, st.a
    tan = -a / np.linalg.norm(a, axis=-1, keepdims=True)       # along the calf, B -> Q
    nrm = np.stack([-tan[:, 1], tan[:, 0]], -1)                 # web normal: tangent turned +90 deg
    psi = np.unwrap(np.arctan2(tan[:, 1], tan[:, 0]))
    om = np.gradient(psi, dt)
    d = lambda x: np.gradient(x, dt, axis=0)  # noqa: E731
    v_q, water = d(q), np.array([-flow, 0.0])
    a_q = d(v_q)
    rel = water - v_q
    v_n_body = np.einsum("ti,ti->t", -rel, nrm)
    dvn = d(v_n_body)
    a_n = np.einsum("ti,ti->t", a_q, nrm)
    out = np.zeros((len(t), 6))

    def normal_at_q(f_n):
        return _point_wrench(f_n * nrm[:, 0], f_n * nrm[:, 1], q[:, 0], q[:, 1], G.web_offset_x_m)

    # normal-force law over the chord (24-point midpoint rule) and its couple about Q
    s = (np.arange(24) + 0.5) / 24 * L - L / 2
    vs = rel[:, None, :] - (om[:, None] * s[None, :])[..., None] * nrm[:, None, :]
    fs = 0.5 * RHO * L * np.hypot(vs[..., 0], vs[..., 1]) * np.einsum("tsi,ti->ts", vs, nrm)
    f_law, m_law = fs.sum(1) * L / 24, (fs * s).sum(1) * L / 24
    law = normal_at_q(f_law)
    law[:, 3] += m_law
    out += PLANT["normal_force_law.c_n90"] * law
    rate = np.maximum(np.hypot(rel[:, 0], rel[:, 1]), 0.05) / L
    for key, tau in (("wagner_lag.a_slow", 1 / (2 * 0.0455)), ("wagner_lag.a_fast", 1 / (2 * 0.3))):
        lf, lm = _lag(f_law, rate / tau, dt), _lag(m_law, rate / tau, dt)
        w = normal_at_q(lf - f_law)
        w[:, 3] += lm - m_law
        out += PLANT[key] * w
    # added mass: the rotating-plate part, and KC growth on the whole d/dt(v_n)
    amp = 0.5 * np.hypot(np.ptp(q[:, 0]), np.ptp(q[:, 1]))
    kc = 2 * np.pi * amp / L
    out += normal_at_q(-PLANT["rotating_added_mass.m_a_kg"] * (dvn - a_n))
    out += normal_at_q(-PLANT["added_mass_kc.m_kc_kg"] * kc ** (2 / 3) * dvn)
    # the web's mass along its tangent, the lateral force
    a_t = np.einsum("ti,ti->t", a_q, tan)
    ft = -PLANT["link_inertia.web_t_kg"] * a_t
    out += _point_wrench(ft * tan[:, 0], ft * tan[:, 1], q[:, 0], q[:, 1], G.web_offset_x_m)
    # the lateral force: a share of the chord-integrated normal force, its lagged parts through the same lags
    fx = PLANT["lateral_force.c_lat"] * f_law
    for key, tau in (("lateral_force.c_lat_slow", 1 / (2 * 0.0455)), ("lateral_force.c_lat_fast", 1 / (2 * 0.3))):
        fx = fx + PLANT[key] * (_lag(f_law, rate / tau, dt) - f_law)
    out[:, 0] += fx
    # skin friction along the web (its tangent) at Q, and the web's rotational added inertia (a tx couple)
    v_t = np.einsum("ti,ti->t", rel, tan)
    f_fric = PLANT["tangential_friction.c_t"] * 0.5 * RHO * L * L * np.abs(v_t) * v_t
    out += _point_wrench(f_fric * tan[:, 0], f_fric * tan[:, 1], q[:, 0], q[:, 1], G.web_offset_x_m)
    out[:, 3] -= PLANT["web_added_inertia.i_kgm2"] * d(om)
    out[:, 4] += q[:, 1] * fx
    out[:, 5] -= q[:, 0] * fx
    # thigh (O-C) and calf (B to the web's near edge): inertia per length, spread weight
    calf_len = G.bq_over_bc * G.bc_m - L / 2
    u = (np.arange(24) + 0.5) / 24
    for name, length, pts in (("thigh", G.oc_m, [uu * c for uu in u]),
                              ("calf", calf_len, [c + (1 - uu * calf_len / G.oa_m) * a for uu in u])):
        for p in pts:
            acc = d(d(p))
            dl = length / 24
            out += _point_wrench(-PLANT["link_inertia.m_kgpm"] * dl * acc[:, 0],
                                 -PLANT["link_inertia.m_kgpm"] * dl * acc[:, 1], p[:, 0], p[:, 1], 0.01)
            net = PLANT[f"link_weight_buoyancy.net_{name}_n"] / 24
            out += _point_wrench(0 * p[:, 0], net + 0 * p[:, 0], p[:, 0], p[:, 1], 0.01)
    out += _point_wrench(0 * q[:, 0], PLANT["link_weight_buoyancy.net_web_n"] + 0 * q[:, 0], q[:, 0], q[:, 1],
                         G.web_offset_x_m)
    return out


@pytest.fixture(scope="module")
def campaign():
    rng = np.random.default_rng(3)
    rows = []
    for i, (hmin, kmax, f, phi) in enumerate(SETS):
        params = dict(theta_h_min_deg=hmin, theta_h_max_deg=-100.0, theta_k_min_deg=80.0, theta_k_max_deg=kmax,
                      frequency_hz=f, phi_rad=phi, alpha_rad=0.0)
        t_fine = np.arange(-0.5 * 650, (3 / f + 0.5) * 650) / 650
        t_fine = t_fine - t_fine[0] - 0.5
        for flow in SPEEDS:
            js = JointSinusoid.from_params(params)
            tt = t_fine[::FINE]
            th, tk, wh, wk, ah, ak = js.evaluate(tt)
            m = LegMotion.from_arrays(1 / 65, th, tk, wh, wk, np.full_like(th, flow), ah, ak)
            y = EmpiricalFormula().wrench(m)[0] + _planted(params, flow, t_fine)[::FINE]
            y[:, :3] += rng.normal(0, 0.002, (len(tt), 3))
            y[:, 3:] += rng.normal(0, 0.0001, (len(tt), 3))
            row = {"run_id": [f"s{i}-u{flow}"] * len(tt), "time_s": tt, "flow_speed_mps": [flow] * len(tt),
                   "theta_h_deg": th, "theta_k_deg": tk, "omega_h_dps": wh, "omega_k_dps": wk}
            row.update({k: [v] * len(tt) for k, v in params.items()})
            row.update({ch: y[:, j] for j, ch in enumerate(WRENCH_CHANNELS)})
            rows.append(pl.DataFrame(row))
    return prepare(pl.concat(rows), DataSettings(heldout_fraction=0.3, tick_stride=1))


@pytest.mark.slow
def test_planted_force_effects_come_back_with_their_parameters(campaign):
    effects = [NormalForceLaw(), WagnerLag(), RotatingAddedMass(), AddedMassKC(), LinkInertia(), LateralForce(),
               LinkWeightBuoyancy(), AddedMassError(), DragCoefficientError(), TangentialFriction(), WebAddedInertia()]
    cfg = Configuration([Active(e, {}) for e in effects])
    names = [f"{e.name}.{n}" for e in effects for n in e.linear_names()]
    problem = Problem(campaign, EmpiricalFormula(), None, FitSettings())
    f = problem.fit(cfg, names=names)
    got, se = f.coefs(), f.stderr()
    for k, v in PLANT.items():
        assert abs(got[k] - v) <= 0.05 * abs(v) + 3 * se[k], (k, got[k], v, se[k])
        assert se[k] < 0.1 * abs(v), (k, se[k])
    # nothing planted on a_n or |V_n| V_n: those two stay near zero
    assert abs(got["added_mass_error.delta_kg"]) < 0.01 and abs(got["drag_coefficient_error.delta_c"]) < 0.05
    # the planted part of the held-out error is gone
    base = problem.fit(Configuration(), names=[])
    h = f.grams.heldout
    before = base.sse_block_c[h].sum(0)
    after = f.sse_block_c[h].sum(0)
    assert np.all(after[[1, 2, 3]] < 0.05 * before[[1, 2, 3]]), after / before


def test_kc_is_a_property_of_the_run_and_the_rotating_term_vanishes_without_rotation():
    from workbench.diagnose.flowterms import LegKinematics

    t = np.arange(0, 4, 1 / 65)
    js = JointSinusoid(-10.0, -100.0, 80.0, -40.0, 0.5, 2.0, 0.0)
    th, tk, wh, wk, ah, ak = js.evaluate(t)
    pad = lambda x, v: np.concatenate([x, np.full(40, v)])  # noqa: E731
    m1 = LegMotion.from_arrays(1 / 65, th, tk, wh, wk, np.full_like(th, 0.2), ah, ak)
    m2 = LegMotion.from_arrays(1 / 65, pad(th, th[-1]), pad(tk, tk[-1]), pad(wh, 0.0), pad(wk, 0.0),
                               np.full(len(th) + 40, 0.2), pad(ah, 0.0), pad(ak, 0.0))
    k1, k2 = LegKinematics(m1), LegKinematics(m2)
    assert k1.kc[0, 0] == pytest.approx(k2.kc[0, 0]) and 3 < k1.kc[0, 0] < 20
    # a leg held still in the flow: no rotation, no rotating-plate force
    still = LegMotion.from_arrays(1 / 65, np.full(50, -40.0), np.full(50, -30.0), np.zeros(50), np.zeros(50),
                                  np.full(50, 0.2), np.zeros(50), np.zeros(50))
    assert np.abs(LegKinematics(still).omega_v_t).max() == 0.0
    assert np.abs(k1.omega_v_t).max() > 0.1 * np.abs(k1.rel_acc_n).max()   # a paddling leg: not small


def test_truth_reference_gives_the_rich_truths_values_in_the_librarys_terms():
    from workbench.diagnose.library import truth_reference
    from workbench.virtual_lab.physics import TrueLegModel

    ref = truth_reference(TrueLegModel("rich").describe())
    m_a = 1000 * 0.579 * np.pi / 4 * 0.06 ** 3                      # DNV flat plate, 98 g
    assert ref["rotating_added_mass"]["m_a_kg"] == pytest.approx(m_a)
    assert ref["added_mass_kc"]["m_kc_kg"] == pytest.approx(0.25 * m_a)
    # the EF puts 2 pi rho a^3 + 10 g on a_n; the truth m_a + 10 g (its web mass)
    assert ref["added_mass_error"]["delta_kg"] == pytest.approx(m_a + 0.010 - 2 * np.pi * 1000 * 0.03 ** 3 - 0.010)
    assert ref["wagner_lag"]["a_slow"] == pytest.approx(0.165 * 1.17)
    assert ref["wagner_lag"]["tau_fast_chords"] == pytest.approx(1 / 0.6)
    # the lateral force: 3 % of the lagged normal force, so 3 % of each of its terms
    assert ref["tangential_friction"] == {"c_t": 0.03}
    assert ref["web_added_inertia"]["i_kgm2"] == pytest.approx(1000 * np.pi * 0.03 ** 4 / 8 * 0.06)   # 1.9e-5
    assert ref["lateral_force"] == pytest.approx({"c_lat": 0.03 * 1.17, "c_lat_slow": 0.03 * 0.165 * 1.17,
                                                  "c_lat_fast": 0.03 * 0.335 * 1.17})
    assert ref["link_weight_buoyancy"]["net_n"] == pytest.approx(
        9.81 * ((1000 * 18.5e-6 - 0.020) + (1000 * 11e-6 - 0.012) + (1000 * 10.8e-6 - 0.010)))   # -0.017 N
    assert truth_reference(TrueLegModel("ef").describe()) == {}
