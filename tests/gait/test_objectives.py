"""Objectives of paper Table III on hand-made and simulated trajectories; the score S."""

import math

import numpy as np
import pytest

from workbench.gait.objectives import TaskSpec, objectives, score, straight_objectives, turn_objectives
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.simulator import GaitBatch, Trajectory, simulate


def _traj(t, x, y, yaw, force=None):
    b, n = x.shape
    force = np.zeros((b, n, 6)) if force is None else force
    gaits = GaitBatch.from_arrays([-20.0] * b, [-50.0] * b, [0.5] * b, np.zeros((b, 4)))
    zeros = np.zeros((b, n))
    return Trajectory(t_s=t, x_m=x, y_m=y, yaw_rad=yaw, vx_mps=zeros, vy_mps=zeros, yaw_rate_rps=zeros,
                      leg_wrench=np.zeros((b, 4, n, 6)), body_wrench=force, leg_flow_mps=np.zeros((b, 4, n)),
                      gaits=gaits, model="test", iterations=1, residual_mps=np.zeros(b), converged=np.ones(b, bool))


def test_straight_time_to_finish_interpolates_between_ticks_and_caps():
    t = np.arange(0, 10.0001, 0.1)
    y = np.stack([0.13 * t, 0.05 * t])            # reaches 1 m at 7.6923 s; never (0.5 m at 10 s)
    yaw = np.stack([0.02 * t, -0.01 * t])
    force = np.zeros((2, t.size, 6))
    force[..., 1] = 0.3                            # constant forward force, no yaw: impulse 0.3 t
    spec = TaskSpec("straight", cap_s=10.0, finish_distance_m=1.0)
    f = straight_objectives(_traj(t, np.zeros_like(y), y, yaw, force), spec)
    t_fin = 1.0 / 0.13
    assert f[0, 2] == pytest.approx(t_fin, rel=1e-9)
    assert f[1, 2] == pytest.approx(10.0)
    assert f[0, 1] == pytest.approx(0.02 * t_fin, rel=1e-9)
    assert f[1, 1] == pytest.approx(0.1, rel=1e-9)
    # f1 = -sum F_Y dt up to t_final, F_Y = cos(yaw) F_y
    expect = -0.3 * np.sum(np.cos(0.02 * t[t < t_fin]) * 0.1)
    assert f[0, 0] == pytest.approx(expect, rel=2e-3)
    deg = straight_objectives(_traj(t, np.zeros_like(y), y, yaw, force), TaskSpec("straight", cap_s=10.0,
                                                                                   finish_distance_m=1.0,
                                                                                   angle_unit="deg"))
    assert deg[0, 1] == pytest.approx(math.degrees(f[0, 1]))


def test_turn_objectives_on_a_circle_in_each_direction():
    t = np.arange(0, 20.0001, 0.05)
    r, w = 0.3, 0.5                               # radius (m), yaw rate (rad/s): 360 deg at 4 pi s
    x = np.stack([r * (1 - np.cos(w * t)), -r * (1 - np.cos(w * t))])
    y = np.stack([r * np.sin(w * t), r * np.sin(w * t)])
    yaw = np.stack([w * t, -w * t])               # first turns left (ccw), second right
    tr = _traj(t, x, y, yaw)
    t360 = 2 * np.pi / w
    either = turn_objectives(tr, TaskSpec("turn", cap_s=20.0, target_yaw_deg=360.0))
    np.testing.assert_allclose(either[:, 2], t360, rtol=1e-9)
    np.testing.assert_allclose(either[:, 1], 0.0, atol=1e-9)
    np.testing.assert_allclose(either[:, 0], 2 * np.pi * r, rtol=1e-3)   # chords of the circle
    left = turn_objectives(tr, TaskSpec("turn", cap_s=20.0, target_yaw_deg=360.0, turn_direction="left"))
    assert left[0, 2] == pytest.approx(t360) and left[1, 2] == pytest.approx(20.0)
    assert left[1, 1] == pytest.approx(2 * np.pi + w * 20.0)           # turned 10 rad the wrong way


def test_score_weights():
    f = np.array([[1.0, 2.0, 3.0], [-1.0, 0.0, 10.0]])
    np.testing.assert_allclose(score(f, (1, 4, 2)), [15.0, 19.0])


def test_straight_impulse_is_the_momentum_at_the_finish(robot):
    # a mirror-symmetric gait swims straight: world Y = body y, and the integrator's momentum balance
    # makes the impulse up to t_final exactly m_y * v_y(t_final)
    g = GaitBatch.from_arrays(-20.0, -60.0, 0.6, [[0.4, 0.4, 3.5, 3.5]])
    tr = simulate(g, EmpiricalFormula(), robot, duration_s=10.0)
    spec = TaskSpec("straight", cap_s=10.0, finish_distance_m=0.3)
    f = objectives(tr, spec)
    assert f[0, 2] < 10.0 and f[0, 1] < 1e-12
    v = np.interp(f[0, 2], tr.t_s, tr.vy_mps[0])
    assert f[0, 0] == pytest.approx(-robot.mass_y_kg * v, rel=1e-9)


def test_task_spec_refuses_nonsense():
    with pytest.raises(ValueError):
        TaskSpec("swim")
    with pytest.raises(ValueError):
        TaskSpec("turn", target_yaw_deg=0.0)
    with pytest.raises(ValueError):
        TaskSpec("turn", turn_direction="up")
    from workbench.errors import ParamsError

    with pytest.raises(ParamsError, match=r"optimize\.tasks\.straight\.finish_m: unknown setting 'finish_m' "
                                          r"\(did you mean 'finish_distance_m'\?"):
        TaskSpec.from_dict("straight", {"finish_m": 2.0})
