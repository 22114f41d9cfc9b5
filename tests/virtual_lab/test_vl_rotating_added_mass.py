"""The rich truth's rotating-plate added-mass term, checked against its own formula.

A plate's added-mass force along its normal is ``-m_a d/dt(v_n)``, ``v_n`` the normal velocity of
the web relative to the water. Here ``d/dt(v_n)`` is taken by finite differences of the web
centre's path and of the web's direction (nothing from the truth's analytic kinematics), and the
part the EF keeps (``a . n``, also from finite differences) is subtracted: what is left is the
rotating-plate term the truth gains.
"""

import numpy as np

from workbench.hydro.kinematics import DEFAULT_GEOMETRY, leg_state
from workbench.hydro.motion import LegMotion
from workbench.virtual_lab.physics import TrueLegModel

RATE = 2000.0  # fine ticks: centred differences are accurate to ~1e-6 of the signal


def _motion(flow):
    t = np.arange(0, 3.0, 1 / RATE)
    f = 0.6
    th = -45.0 + 30.0 * np.sin(2 * np.pi * f * t)            # deg, a paddling stroke
    tk = -40.0 + 25.0 * np.sin(2 * np.pi * f * t + 1.2)
    wh = 30.0 * 2 * np.pi * f * np.cos(2 * np.pi * f * t)
    wk = 25.0 * 2 * np.pi * f * np.cos(2 * np.pi * f * t + 1.2)
    ah = -30.0 * (2 * np.pi * f) ** 2 * np.sin(2 * np.pi * f * t)
    ak = -25.0 * (2 * np.pi * f) ** 2 * np.sin(2 * np.pi * f * t + 1.2)
    one = np.ones((1, len(t)))
    return t, LegMotion.from_arrays(1 / RATE, th * one, tk * one, wh * one, wk * one, flow * one, ah * one, ak * one)


def test_truth_adds_m_a_omega_v_t_along_the_normal():
    g = DEFAULT_GEOMETRY
    for flow in (0.0, 0.25):
        t, m = _motion(flow)
        with_rot = TrueLegModel("rich").wrench(m)[0]
        without = TrueLegModel("rich").with_params(rotating_added_mass=False).wrench(m)[0]
        diff = with_rot - without

        # the web centre Q and the web's direction from the joint angles only
        st = leg_state(np.radians(m.theta_h_deg[0]), np.radians(m.theta_k_deg[0]), geometry=g)
        q = st.q
        along = st.tangent                         # unit vector along the web, in the leg plane
        normal = np.stack([-along[:, 1], along[:, 0]], axis=-1)   # turned +90 degrees
        dt = 1 / RATE
        v_q = np.gradient(q, dt, axis=0)
        a_q = np.gradient(v_q, dt, axis=0)
        water = np.array([-flow, 0.0])
        v_n = np.einsum("ti,ti->t", v_q - water, normal)
        dvn_dt = np.gradient(v_n, dt)
        rotating = dvn_dt - np.einsum("ti,ti->t", a_q, normal)   # what a_n alone misses

        # the truth's added mass: DNV flat plate, grown with KC = 2 pi A / L (A: half the diagonal of Q's path box)
        amp = 0.5 * np.hypot(np.ptp(q[:, 0]), np.ptp(q[:, 1]))
        kc = 2 * np.pi * amp / g.web_side_m
        p = TrueLegModel("rich").params
        m_a = p.rho_kgpm3 * p.added_mass_coeff * np.pi / 4 * g.web_side_m ** 3 * (1 + p.kc_gain * kc ** (2 / 3))
        force = -m_a * rotating[:, None] * normal                 # leg plane (X, Y) = load cell (y, z)
        inner = slice(50, -50)
        scale = np.abs(force).max()
        assert scale > 0.02                                         # tens of mN: a real term, not rounding
        np.testing.assert_allclose(diff[inner, 1], force[inner, 0], atol=2e-3 * scale)
        np.testing.assert_allclose(diff[inner, 2], force[inner, 1], atol=2e-3 * scale)
        # its moment about the hip (tx = X f_Y - Y f_X, Q in the leg plane) and no lateral part
        tx = q[:, 0] * force[:, 1] - q[:, 1] * force[:, 0]
        np.testing.assert_allclose(diff[inner, 3], tx[inner], atol=2e-3 * np.abs(tx).max())
        assert np.abs(diff[:, 0]).max() < 1e-12


def test_rotating_term_is_on_by_default_and_described():
    d = TrueLegModel("rich").describe()
    assert d["params"]["rotating_added_mass"] is True
