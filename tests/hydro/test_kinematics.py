"""Four-bar leg kinematics: link lengths, the assembly branch, analytic rates against finite differences."""

import numpy as np
import pytest

from workbench.hydro.kinematics import DEFAULT_GEOMETRY as G
from workbench.hydro.kinematics import leg_state
from workbench.hydro.motion import JointSinusoid

# the paper's workspace: theta_h in [-100, 10] deg, theta_k in [-80, 80] deg
TH, TK = np.meshgrid(np.radians(np.linspace(-100, 10, 45)), np.radians(np.linspace(-80, 80, 41)), indexing="ij")


def _norm(v):
    return np.linalg.norm(v, axis=-1)


def _cross2(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def test_link_lengths_hold_over_the_workspace():
    st = leg_state(TH, TK)
    o = np.zeros_like(st.a)
    np.testing.assert_allclose(_norm(st.a - o), 0.035, rtol=1e-12)
    np.testing.assert_allclose(_norm(st.c - st.b), 0.035, rtol=1e-12)
    np.testing.assert_allclose(_norm(st.c - o), 0.125, rtol=1e-12)
    np.testing.assert_allclose(_norm(st.b - st.a), 0.125, rtol=1e-12)
    np.testing.assert_allclose(_norm(st.q - st.b), 2.5 * _norm(st.c - st.b), rtol=1e-12)
    # Q lies on the calf line B -> C, beyond C
    np.testing.assert_allclose(_cross2(st.c - st.b, st.q - st.b), 0.0, atol=1e-15)
    assert np.all(np.einsum("...i,...i->...", st.c - st.b, st.q - st.b) > 0)


def _circle_intersections(p0, r0, p1, r1):
    d = _norm(p1 - p0)
    a = (r0**2 - r1**2 + d**2) / (2 * d)
    h = np.sqrt(np.maximum(r0**2 - a**2, 0.0))
    u = (p1 - p0) / d[..., None]
    mid = p0 + a[..., None] * u
    perp = np.stack([-u[..., 1], u[..., 0]], axis=-1)
    return mid + h[..., None] * perp, mid - h[..., None] * perp


def test_b_is_the_intersection_on_the_far_side_of_ac_from_o():
    st = leg_state(TH, TK)
    p, m = _circle_intersections(st.a, G.ab_m, st.c, G.bc_m)
    ac = st.c - st.a
    side_o = np.sign(_cross2(ac, -st.a))
    far = np.where((np.sign(_cross2(ac, p - st.a)) != side_o)[..., None], p, m)
    np.testing.assert_allclose(st.b, far, atol=1e-12)
    # both candidates really lie on both circles (the test's own geometry is right)
    for cand in (p, m):
        np.testing.assert_allclose(_norm(cand - st.a), G.ab_m, rtol=1e-9)
        np.testing.assert_allclose(_norm(cand - st.c), G.bc_m, rtol=1e-9)


def test_literal_larger_y_rule_would_switch_branches_inside_the_workspace():
    # why the code uses the parallelogram branch: the fixed-frame "larger Y" choice is not it everywhere
    st = leg_state(TH, TK)
    p, m = _circle_intersections(st.a, G.ab_m, st.c, G.bc_m)
    larger_y = np.where((p[..., 1] >= m[..., 1])[..., None], p, m)
    differs = _norm(larger_y - st.b) > 1e-9
    assert differs.any() and not differs.all()


@pytest.mark.parametrize("params", [
    dict(theta_h_min_deg=10, theta_h_max_deg=-100, theta_k_min_deg=80, theta_k_max_deg=-20, frequency_hz=0.6,
         phi_rad=np.pi / 3),
    dict(theta_h_min_deg=-50, theta_h_max_deg=-100, theta_k_min_deg=80, theta_k_max_deg=-80, frequency_hz=0.3,
         phi_rad=5 * np.pi / 3, alpha_rad=1.0),
])
def test_analytic_velocity_and_acceleration_match_finite_differences(params):
    s = JointSinusoid(**params)
    t = np.linspace(0, 1 / params["frequency_hz"], 97)
    h = 1e-5

    def state(tt):
        th, tk, wh, wk, ah, ak = s.evaluate(tt)
        return leg_state(*np.radians([th, tk, wh, wk, ah, ak]))

    st, plus, minus = state(t), state(t + h), state(t - h)
    np.testing.assert_allclose(st.q_vel, (plus.q - minus.q) / (2 * h), atol=1e-7)
    np.testing.assert_allclose(st.q_acc, (plus.q_vel - minus.q_vel) / (2 * h), atol=1e-6)
    h2 = 1e-4
    p2, m2 = state(t + h2), state(t - h2)
    np.testing.assert_allclose(st.q_acc, (p2.q - 2 * st.q + m2.q) / h2**2, atol=1e-4)
    # the web turns with the calf: web_rate is the calf angle's rate
    ang = lambda x: np.unwrap(np.arctan2(x.tangent[..., 1], x.tangent[..., 0]))  # noqa: E731
    np.testing.assert_allclose(st.web_rate, (ang(plus) - ang(minus)) / (2 * h), atol=1e-6)
    assert np.abs(st.q_vel).max() > 0.05  # the motion is not trivially still


def test_web_normal_and_tangent():
    st = leg_state(TH, TK)
    np.testing.assert_allclose(_norm(st.normal), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.einsum("...i,...i->...", st.normal, st.tangent), 0.0, atol=1e-15)
    # tangent runs from B towards Q along the calf; normal is it turned +90 degrees
    calf = (st.q - st.b) / _norm(st.q - st.b)[..., None]
    np.testing.assert_allclose(st.tangent, calf, atol=1e-12)
    np.testing.assert_allclose(_cross2(st.tangent, st.normal), 1.0, rtol=1e-12)


def test_hand_computed_pose():
    # thigh straight down (theta_h = -90 deg); psi = theta_h + theta_k + 90 deg
    st = leg_state(np.radians(-90.0), np.radians(90.0))  # psi = 90 deg: crank straight up
    np.testing.assert_allclose(st.c, [0.0, -0.125], atol=1e-15)
    np.testing.assert_allclose(st.a, [0.0, 0.035], atol=1e-15)
    np.testing.assert_allclose(st.b, [0.0, -0.090], atol=1e-15)
    np.testing.assert_allclose(st.q, [0.0, -0.125 - 1.5 * 0.035], atol=1e-15)
    np.testing.assert_allclose(st.normal, [1.0, 0.0], atol=1e-15)  # calf vertical: web faces forward


def test_vectorised_over_any_shape():
    th = np.radians(np.full((3, 4, 5), -40.0))
    st = leg_state(th, 0.2, 0.5, -0.3)
    assert st.q.shape == (3, 4, 5, 2) and st.q_vel.shape == (3, 4, 5, 2) and st.web_rate.shape == (3, 4, 5)
    one = leg_state(np.radians(-40.0), 0.2, 0.5, -0.3)
    np.testing.assert_allclose(st.q_vel[1, 2, 3], one.q_vel)
