"""The paper's EF against hand-computed cases, its sign conventions, and the leg-model interface."""

from dataclasses import replace

import numpy as np
import pytest

from workbench.errors import ModelError
from workbench.hydro.ef import EFParams, EmpiricalFormula
from workbench.hydro.legmodel import LegForceModel, load_leg_model
from workbench.hydro.motion import JointSinusoid, LegMotion

# pose used by hand: theta_h = -80, theta_k = 80 -> crank straight up (psi = 90 deg), calf vertical,
# web normal = +X (forward, the load cell's +y); Q = C - 1.5 A
C = 0.125 * np.array([np.cos(np.radians(-80)), np.sin(np.radians(-80))])  # (0.0217060, -0.1231010)
QX, QY = C[0], C[1] - 1.5 * 0.035  # (0.0217060, -0.1756010)
K_DRAG = 0.5 * 1000 * 0.06**2 * 0.7  # 0.5 rho S C_R = 1.26 N s^2/m^2
M_TOTAL = 2 * np.pi * 1000 * 0.03**3 + 0.010  # 0.169646 + 0.010 kg


def _still(flow, omega_h=0.0, alpha_h=0.0, n=5):
    return LegMotion.from_arrays(0.01, np.full(n, -80.0), np.full(n, 80.0), omega_h, 0.0, flow, alpha_h, 0.0)


def _wrench_at(fy, fz=0.0):
    """Hand: force (0, fy, fz) at r = (0.02, QX, QY): tau = r x F."""
    return np.array([0.0, fy, fz, QX * fz - QY * fy, -0.02 * fz, 0.02 * fy])


def test_pure_flow_on_a_still_leg_is_drag_only():
    ef = EmpiricalFormula()
    w = ef.wrench(_still(0.2))
    fy = -K_DRAG * 0.2**2  # -0.0504 N: the flow pushes the web downstream (-y)
    np.testing.assert_allclose(w[0], np.tile(_wrench_at(fy), (5, 1)), atol=1e-12)
    np.testing.assert_allclose(fy, -0.0504)
    # quadratic in the flow and odd in its direction
    np.testing.assert_allclose(ef.wrench(_still(0.4))[0, 0], 4 * w[0, 0], rtol=1e-12)
    np.testing.assert_allclose(ef.wrench(_still(-0.2))[0, 0], -w[0, 0], rtol=1e-12)


def test_pure_acceleration_at_zero_flow_is_added_mass_plus_web_inertia():
    # the whole leg starts turning about the hip (theta_k fixed): a_n = alpha * |QY| at Q, forward
    alpha = 1.0  # rad/s^2
    w = EmpiricalFormula().wrench(_still(0.0, alpha_h=np.degrees(alpha)))
    a_n = alpha * (-QY)  # 0.175601 m/s^2
    fy = -M_TOTAL * a_n  # reaction of added mass and web inertia: against the acceleration
    np.testing.assert_allclose(fy, -0.031546, rtol=1e-5)
    np.testing.assert_allclose(w[0, 2], _wrench_at(fy), atol=1e-12)
    # the two terms separately: without added mass only the 10 g web is left
    no_added = EmpiricalFormula(EFParams(added_mass_factor=0.0)).wrench(_still(0.0, alpha_h=np.degrees(alpha)))
    np.testing.assert_allclose(no_added[0, 2, 1], -0.010 * a_n, rtol=1e-12)


def test_drag_uses_the_velocity_relative_to_the_flow():
    omega = 1.0  # rad/s, whole leg turning: Q moves forward at omega |QY|, centripetal a_n = -omega^2 QX
    v_q = omega * (-QY)
    inertial = -M_TOTAL * (-(omega**2) * QX)
    moving = EmpiricalFormula().wrench(_still(0.0, omega_h=np.degrees(omega)))
    # web moving forward through still water: drag pushes it back
    np.testing.assert_allclose(moving[0, 2, 1], inertial - K_DRAG * v_q**2, rtol=1e-9)
    # water moving with the web (flow along +y at the web's speed): no drag, inertia only
    carried = EmpiricalFormula().wrench(_still(-v_q, omega_h=np.degrees(omega)))
    np.testing.assert_allclose(carried[0, 2, 1], inertial, rtol=1e-9)


def test_force_is_along_the_web_normal_and_never_lateral():
    s = JointSinusoid(-20, -100, 80, -50, 0.5, np.pi / 3)
    t = np.arange(0, 2, 0.01)
    ef = EmpiricalFormula()
    motion = s.motion(t, 0.15)
    w = ef.wrench(motion)
    f_n, st = ef.normal_force(motion)
    assert np.all(w[..., 0] == 0)  # no fx: the EF has no out-of-plane force
    np.testing.assert_allclose(w[..., 1:3], f_n[..., None] * st.normal, atol=1e-15)
    # torque is r x F with the web 0.02 m off the hip axis
    r = np.stack([np.full(f_n.shape, 0.02), st.q[..., 0], st.q[..., 1]], axis=-1)
    np.testing.assert_allclose(w[..., 3:], np.cross(r, w[..., :3]), atol=1e-15)


def test_gradient_accelerations_approach_the_analytic_ones():
    s = JointSinusoid(10, -100, 80, -20, 0.4, np.pi / 3)
    t = np.arange(0, 5, 1 / 65)
    m = s.motion(t, 0.1)
    m_fd = replace(m, alpha_h_dps2=None, alpha_k_dps2=None)
    ef = EmpiricalFormula()
    a, b = ef.wrench(m), ef.wrench(m_fd)
    assert np.abs(a - b)[:, 2:-2].max() < 0.01 * np.abs(a).max()


def test_flow_provider_equals_wrench():
    s = JointSinusoid(-30, -100, 80, -60, 0.55, np.pi / 3, 0.7)
    t = np.arange(0, 3, 1 / 65)
    m = s.motion(t, 0.0)
    flow = 0.1 + 0.05 * np.sin(t)[None, :]
    ef = EmpiricalFormula()
    np.testing.assert_allclose(ef.flow_provider(m)(flow), ef.wrench(replace(m, flow_speed_mps=flow)),
                               rtol=1e-12, atol=1e-15)


def test_load_leg_model_finds_ef_and_refuses_unknown():
    assert isinstance(load_leg_model("ef"), EmpiricalFormula)
    assert isinstance(load_leg_model("ef"), LegForceModel)
    with pytest.raises(ModelError, match="unknown leg force model"):
        load_leg_model("no-such-model")
