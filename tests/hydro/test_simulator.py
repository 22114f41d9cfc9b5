"""Full-body simulator: symmetry, mirror images, impulse balance, the fixed point, batching, determinism."""

import numpy as np
import pytest

from workbench.errors import ModelError
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.motion import JointSinusoid, LegMotion
from workbench.hydro.robot import RobotSettings
from workbench.hydro.simulator import (
    DEFAULT_DT_S,
    BodyDrag,
    GaitBatch,
    integrate_stepwise,
    leg_flow_speeds,
    legs_to_body,
    simulate,
)

ROBOT = RobotSettings()
EF = EmpiricalFormula()


def _gaits(alpha, th=-20.0, tk=-50.0, f=0.5):
    return GaitBatch.from_arrays(th, tk, f, np.atleast_2d(alpha))


def test_mirror_image_gait_swims_straight_without_yaw_drift():
    tr = simulate(_gaits([0.5, 0.5, 3.6, 3.6]), EF, ROBOT, duration_s=20)
    assert np.abs(tr.x_m).max() < 1e-12
    assert np.abs(tr.yaw_rad).max() < 1e-12
    assert np.abs(tr.total_wrench[..., 0]).max() < 1e-12 and np.abs(tr.total_wrench[..., 5]).max() < 1e-12
    assert tr.y_m[0, -1] > 0.2  # and it does swim forward


def test_mirrored_gaits_give_mirrored_trajectories():
    g = GaitBatch.from_arrays([-20.0, 10.0], [-50.0, -20.0], [0.55, 0.4], [[0.3, 1.9, 4.0, 5.5], [0.0, 3.1, 0.0, 3.1]])
    a = simulate(g, EF, ROBOT, duration_s=15)
    b = simulate(g.mirrored(), EF, ROBOT, duration_s=15)
    assert np.abs(a.yaw_rad[:, -1]).min() > 0.05  # these gaits do turn
    np.testing.assert_allclose(b.x_m, -a.x_m, atol=1e-9)
    np.testing.assert_allclose(b.y_m, a.y_m, atol=1e-9)
    np.testing.assert_allclose(b.yaw_rad, -a.yaw_rad, atol=1e-9)
    np.testing.assert_allclose(b.vx_mps, -a.vx_mps, atol=1e-9)
    np.testing.assert_allclose(b.yaw_rate_rps, -a.yaw_rate_rps, atol=1e-9)
    np.testing.assert_allclose(b.leg_flow_mps, a.leg_flow_mps[:, [1, 0, 3, 2]], atol=1e-9)


def test_impulse_balance_at_steady_speed():
    # f = 0.5 Hz with dt = 1/65 s: one cycle is exactly 130 ticks
    tr = simulate(_gaits([0.0, 0.0, np.pi, np.pi]), EF, ROBOT, duration_s=30)
    n = 130
    thrust = tr.leg_thrust_n[0, -n - 1:-1]
    drag = tr.body_wrench[0, -n - 1:-1, 1]
    # discrete momentum balance over the cycle holds exactly (straight swim: no Coriolis terms)
    dv = tr.vy_mps[0, -1] - tr.vy_mps[0, -n - 1]
    np.testing.assert_allclose(ROBOT.mass_y_kg * dv, (thrust + drag).sum() * DEFAULT_DT_S, atol=1e-12)
    # at steady speed the cycle-averaged leg thrust equals the body drag
    assert thrust.mean() > 0.01
    assert abs(thrust.mean() + drag.mean()) < 1e-3 * abs(drag.mean())


def _stepped_ef(gaits, robot, duration_s, dt_s=DEFAULT_DT_S):
    """Reference: the EF stepped tick by tick with the flow of the current state (no fixed point)."""
    t = np.arange(int(round(duration_s / dt_s)) + 1) * dt_s
    motion = gaits.leg_motion(t)
    b = len(gaits)

    def legs(n, v):
        flow = leg_flow_speeds(robot, v[:, 0:1], v[:, 1:2], v[:, 2:3]).reshape(4 * b, 1)
        m = LegMotion(dt_s, *(a[:, n:n + 1] for a in (motion.theta_h_deg, motion.theta_k_deg, motion.omega_h_dps,
                                                      motion.omega_k_dps)), flow,
                      motion.alpha_h_dps2[:, n:n + 1], motion.alpha_k_dps2[:, n:n + 1])
        w = legs_to_body(robot, EF.wrench(m).reshape(b, 4, 1, 6)).sum(axis=1)[:, 0]
        return w[:, [0, 1, 5]]

    return integrate_stepwise(robot, legs, t.size, b, dt_s)


def test_fixed_point_matches_direct_stepping_of_the_instantaneous_ef():
    g = GaitBatch.from_arrays([-20.0, 0.0], [-50.0, -70.0], [0.5, 0.3], [[0.3, 1.9, 4.0, 5.5], [0, 0, 0, 0]])
    ref = _stepped_ef(g, ROBOT, 10)
    residuals = []
    tr = simulate(g, EF, ROBOT, duration_s=10, tol_mps=1e-10, max_iter=60,
                  on_iteration=lambda k, r: residuals.append(r.max()))
    assert tr.converged.all() and tr.residual_mps.max() < 1e-10
    assert residuals[-1] < residuals[0] * 1e-6
    for key, arr in (("vx", tr.vx_mps), ("vy", tr.vy_mps), ("r", tr.yaw_rate_rps), ("x", tr.x_m), ("y", tr.y_m),
                     ("yaw", tr.yaw_rad)):
        np.testing.assert_allclose(arr, ref[key], atol=1e-8, err_msg=key)
    # the default tolerance is close to it too
    loose = simulate(g, EF, ROBOT, duration_s=10)
    assert loose.converged.all() and loose.iterations <= 12
    assert np.abs(loose.vy_mps - ref["vy"]).max() < 1e-4
    assert np.abs(loose.y_m - ref["y"]).max() < 1e-3


def test_converges_over_the_papers_parameter_ranges():
    rng = np.random.default_rng(7)
    b = 12
    g = GaitBatch.from_arrays(rng.uniform(-50, 10, b), rng.uniform(-80, -20, b), rng.uniform(0.2, 0.65, b),
                              rng.uniform(0, 2 * np.pi, (b, 4)))
    tr = simulate(g, EF, ROBOT, duration_s=20)
    assert tr.converged.all() and tr.iterations <= 20       # leg-model calls, tol 1e-5
    unconverged = simulate(g, EF, ROBOT, duration_s=5, max_iter=1)
    # one iteration per window (retries on shorter windows included) is not enough, and it says so
    assert not unconverged.converged.any() and unconverged.residual_mps.min() > 1e-4


def test_batch_rows_equal_single_runs_and_runs_are_deterministic():
    rng = np.random.default_rng(3)
    g = GaitBatch.from_arrays(rng.uniform(-50, 10, 3), rng.uniform(-80, -20, 3), rng.uniform(0.2, 0.65, 3),
                              rng.uniform(0, 2 * np.pi, (3, 4)))
    batch = simulate(g, EF, ROBOT, duration_s=8)
    again = simulate(g, EF, ROBOT, duration_s=8)
    for name in ("x_m", "y_m", "yaw_rad", "leg_wrench", "body_wrench", "leg_flow_mps"):
        assert np.array_equal(getattr(batch, name), getattr(again, name)), name
    for i in range(3):
        one = simulate(g.rows(i), EF, ROBOT, duration_s=8)
        np.testing.assert_allclose(one.x_m[0], batch.x_m[i], atol=1e-12)
        np.testing.assert_allclose(one.yaw_rad[0], batch.yaw_rad[i], atol=1e-12)
        np.testing.assert_allclose(one.leg_wrench[0], batch.leg_wrench[i], atol=1e-12)


class _WholeHistoryEF(LegForceModel):
    """The EF without its fast path: the simulator must call ``wrench`` each iteration."""

    name = "ef-slow"

    def wrench(self, motion):
        return EF.wrench(motion)


class _BadShape(LegForceModel):
    def wrench(self, motion):
        return np.zeros((*motion.shape, 3))


def test_any_leg_force_model_plugs_in():
    g = _gaits([0.3, 1.9, 4.0, 5.5])
    fast = simulate(g, EF, ROBOT, duration_s=5)
    slow = simulate(g, _WholeHistoryEF(), ROBOT, duration_s=5)
    assert slow.model == "ef-slow"
    np.testing.assert_allclose(slow.y_m, fast.y_m, atol=1e-12)
    with pytest.raises(ModelError, match="shape"):
        simulate(g, _BadShape(), ROBOT, duration_s=1)


def test_leg_wrenches_move_to_the_metacenter_with_mirror_and_haa_rotation():
    w = np.zeros((1, 4, 1, 6))
    w[0, :, 0] = [0.1, -0.2, 0.3, 0.01, -0.02, 0.03]  # the same reading on every leg
    body = legs_to_body(ROBOT, w)[0, :, 0]
    # right legs are mirror images of the left: (fx, fy, fz, tx, ty, tz) -> (-fx, fy, fz, tx, -ty, -tz)
    mirror = np.array([-1, 1, 1, 1, -1, -1])
    np.testing.assert_allclose(body[1], mirror * body[0], atol=1e-15)
    np.testing.assert_allclose(body[3], mirror * body[2], atol=1e-15)
    # hind left leg: no HAA rotation, so F is unchanged and tau = p x F + tau_leg
    p = ROBOT.hip_positions_m()[2]
    np.testing.assert_allclose(body[2, :3], w[0, 2, 0, :3])
    np.testing.assert_allclose(body[2, 3:], np.cross(p, w[0, 2, 0, :3]) + w[0, 2, 0, 3:], atol=1e-15)


def test_leg_flow_and_body_drag():
    flow = leg_flow_speeds(ROBOT, np.array([[0.0]]), np.array([[0.1]]), np.array([[0.0]]))
    np.testing.assert_allclose(flow[0, :, 0], 0.1)
    # pure yaw to the left: the right legs (hip x > 0) move forward, the left legs backward
    flow = leg_flow_speeds(ROBOT, np.array([[0.0]]), np.array([[0.0]]), np.array([[1.0]]))
    np.testing.assert_allclose(flow[0, :, 0], ROBOT.hip_positions_m()[:, 0])
    drag = BodyDrag(ROBOT)
    fx, fy, tz = drag(np.array([0.2, -0.2]), np.array([0.1, 0.0]), np.array([0.0, 0.0]))
    np.testing.assert_allclose(fx, [-ROBOT.lateral_drag.magnitude(0.2), ROBOT.lateral_drag.magnitude(0.2)])
    np.testing.assert_allclose(fy, [-ROBOT.forward_drag.magnitude(0.1), 0.0])
    np.testing.assert_allclose(tz, 0.0, atol=1e-15)
    fx, _, tz = drag(np.array([0.0, 0.0]), np.array([0.0, 0.0]), np.array([0.5, -0.5]))
    assert tz[0] < 0 < tz[1]  # yaw drag opposes the yaw rate
    np.testing.assert_allclose(fx, 0.0, atol=1e-15)


def test_gait_batch_builds_the_papers_joint_motion():
    params = [{"theta_h_min_deg": -30.0, "theta_k_max_deg": -40.0, "frequency_hz": 0.45,
               "alpha_rad": [0.0, 1.0, 2.0, 3.0]}, {"theta_h_min_deg": 10.0, "theta_k_max_deg": -20.0,
                                                  "frequency_hz": 0.6, "alpha_rad": 0.5}]
    g = GaitBatch.from_params(params)
    assert len(g) == 2 and g.to_params()[0] == params[0]
    assert g.to_params()[1]["alpha_rad"] == [0.5] * 4
    t = np.arange(0, 3, DEFAULT_DT_S)
    m = g.leg_motion(t)
    assert m.shape == (8, t.size)
    ref = JointSinusoid(-30, -100, 80, -40, 0.45, np.pi / 3, 2.0).evaluate(t)
    for got, want in zip((m.theta_h_deg[2], m.theta_k_deg[2], m.omega_h_dps[2], m.omega_k_dps[2],
                          m.alpha_h_dps2[2], m.alpha_k_dps2[2]), ref, strict=True):
        np.testing.assert_allclose(got, want)
    with pytest.raises(ValueError):
        GaitBatch.from_arrays(-20, -50, 0.0, [0, 0, 0, 0])
    with pytest.raises(ValueError, match="lack"):
        GaitBatch.from_params([{"theta_h_min_deg": 0}])


def test_trajectory_frame():
    tr = simulate(GaitBatch.from_arrays([-20, -30], -50, 0.5, [[0, 0, 3, 3], [0, 1, 2, 3]]), EF, ROBOT, duration_s=2)
    frame = tr.to_frame([{"label": "a"}, {"label": "b"}])
    assert frame.height == 2 * tr.t_s.size
    for col in ("label", "gait", "time_s", "x_m", "y_m", "yaw_rad", "vx_mps", "vy_mps", "yaw_rate_rps", "fy_n",
                "tz_nm", "body_fy_n", "lf_fy_n", "rh_tz_nm", "lf_flow_mps"):
        assert col in frame.columns
    np.testing.assert_allclose(frame.filter(frame["gait"] == 1)["fy_n"].to_numpy(), tr.total_wrench[1, :, 1])
