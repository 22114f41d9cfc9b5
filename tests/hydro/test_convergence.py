"""The simulator's fixed point over 60 s swims: converged everywhere in the paper's gait space, and right.

The reference is written here, independently of the simulator's iteration: a causal loop that
steps the body tick by tick (its own semi-implicit Euler, its own hip-velocity flow, the legs'
wrenches moved to the body by the einsum map), asking the leg model for the current tick with the
flow history so far. A converged fixed point must reproduce it; an unconverged one must say so.
"""

from dataclasses import replace

import numpy as np
import pytest
from scipy.signal import lfilter

from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.robot import RobotSettings
from workbench.hydro.simulator import DEFAULT_DT_S, BodyDrag, GaitBatch, legs_to_body, simulate

EF = EmpiricalFormula()


@pytest.fixture(scope="module")
def robot():
    return RobotSettings()
_FIELDS = ("theta_h_deg", "theta_k_deg", "omega_h_dps", "omega_k_dps", "alpha_h_dps2", "alpha_k_dps2")


def paper_space_gaits(n, seed):
    """Random gaits of the paper's space (Table II): one range and frequency for all legs, a phase per leg."""
    rng = np.random.default_rng(seed)
    return GaitBatch.from_arrays(rng.uniform(-50, 10, n), rng.uniform(-80, -20, n), rng.uniform(0.2, 0.65, n),
                                 rng.uniform(0, 2 * np.pi, (n, 4)))


def tick_by_tick(gaits, model, robot, duration_s, *, memory, dt_s=DEFAULT_DT_S):
    """(B, T, 3) world pose x, y, yaw from stepping the body tick by tick with the leg model in the loop.

    ``memory``: the model is called on the whole history so far (its last tick is used); otherwise
    on the current tick alone (an instantaneous model).
    """
    b, n = len(gaits), int(round(duration_s / dt_s)) + 1
    motion = gaits.leg_motion(np.arange(n) * dt_s)
    hips, fwd = robot.hip_positions_m(), robot.leg_forward_axes()
    drag = BodyDrag(robot)
    mx, my, iz = robot.mass_x_kg, robot.mass_y_kg, robot.inertia_z_kgm2
    munk = (mx - my) if robot.munk_moment else 0.0
    v, pose = np.zeros((b, 3)), np.zeros((b, 3))
    flow = np.zeros((4 * b, n))
    out = np.zeros((b, n, 3))
    for k in range(n - 1):
        # each hip's velocity through still water along its leg's forward axis
        ux = v[:, None, 0] - v[:, None, 2] * hips[None, :, 1]
        uy = v[:, None, 1] + v[:, None, 2] * hips[None, :, 0]
        flow[:, k] = (ux * fwd[None, :, 0] + uy * fwd[None, :, 1]).ravel()
        lo = 0 if memory else k
        upto = replace(motion, flow_speed_mps=flow[:, lo:k + 1],
                       **{f: getattr(motion, f)[:, lo:k + 1] for f in _FIELDS})
        w = legs_to_body(robot, model.wrench(upto)[:, -1].reshape(b, 4, 1, 6))[:, :, 0].sum(axis=1)
        fx, fy, tz = (w[:, i] + d for i, d in zip((0, 1, 5), drag.planar(v).T, strict=True))
        vx, vy, r = v.T
        v = v + dt_s * np.stack([(fx + my * r * vy) / mx, (fy - mx * r * vx) / my, (tz + munk * vx * vy) / iz], -1)
        mid = pose[:, 2] + 0.5 * dt_s * v[:, 2]
        pose = pose + dt_s * np.stack([np.cos(mid) * v[:, 0] - np.sin(mid) * v[:, 1],
                                       np.sin(mid) * v[:, 0] + np.cos(mid) * v[:, 1], v[:, 2]], -1)
        out[:, k + 1] = pose
    return out


@pytest.mark.slow
def test_random_gaits_converge_over_60_s_and_match_tick_by_tick_stepping(robot):
    gaits = paper_space_gaits(24, seed=11)
    tr = simulate(gaits, EF, robot, duration_s=60.0)
    assert tr.converged.all(), f"unconverged: {np.flatnonzero(~tr.converged)}, residuals {tr.residual_mps}"
    assert tr.residual_mps.max() < 1e-4
    ref = tick_by_tick(gaits, EF, robot, 60.0, memory=False)
    pos_err = np.hypot(tr.x_m - ref[..., 0], tr.y_m - ref[..., 1]).max(axis=1)
    yaw_err = np.abs(tr.yaw_rad - ref[..., 2]).max(axis=1)
    # the swims cover 1-8 m and up to several turns; the fixed point is within millimetres of the stepping
    assert pos_err.max() < 0.01, pos_err
    assert np.degrees(yaw_err.max()) < 0.5
    # and tightening the tolerance closes the gap (the difference is the fixed point's, not the loop's)
    tight = simulate(gaits.rows(slice(0, 6)), EF, robot, duration_s=60.0, tol_mps=1e-9)
    assert tight.converged.all()
    tight_err = np.hypot(tight.x_m - ref[:6, :, 0], tight.y_m - ref[:6, :, 1]).max()
    assert tight_err < 1e-6


class _LaggedFlowEF(LegForceModel):
    """A leg model with memory: the EF seeing the flow through a first-order lag (time constant tau)."""

    name = "ef-lagged-flow"

    def __init__(self, tau_s=0.3):
        self.tau_s = tau_s

    def wrench(self, motion):
        a = 1.0 - np.exp(-motion.dt_s / self.tau_s)
        # causal: y[n] = (1 - a) y[n-1] + a u[n], starting from the first tick's flow
        u = np.asarray(motion.flow_speed_mps, float)
        lagged, _ = lfilter([a], [1.0, a - 1.0], u, axis=1, zi=(1 - a) * u[:, :1])
        return EF.wrench(replace(motion, flow_speed_mps=lagged))

    def describe(self):
        return {"name": self.name, "tau_s": self.tau_s}


@pytest.mark.slow
def test_a_model_with_memory_converges_and_matches_tick_by_tick_stepping(robot):
    gaits = paper_space_gaits(4, seed=5)
    model = _LaggedFlowEF()
    tr = simulate(gaits, model, robot, duration_s=20.0)
    assert tr.converged.all()
    ref = tick_by_tick(gaits, model, robot, 20.0, memory=True)
    assert np.hypot(tr.x_m - ref[..., 0], tr.y_m - ref[..., 1]).max() < 0.005
    # the lag matters: the memoryless EF swims measurably differently
    plain = simulate(gaits, EF, robot, duration_s=20.0)
    assert np.hypot(plain.x_m - tr.x_m, plain.y_m - tr.y_m)[:, -1].max() > 0.02


@pytest.mark.slow
def test_a_result_that_did_not_converge_says_so(robot):
    gaits = paper_space_gaits(3, seed=2)
    short = simulate(gaits, EF, robot, duration_s=30.0, max_iter=2)
    assert not short.converged.any()
    assert np.all(short.residual_mps > 1e-4)
    # the whole-horizon Picard iteration (the earlier scheme) within the same budget of leg-model calls
    full = simulate(gaits, EF, robot, duration_s=30.0)
    picard = simulate(gaits, EF, robot, duration_s=30.0, method="picard", max_iter=full.iterations, relaxation=0.8)
    assert full.converged.all()
    assert picard.residual_mps.max() > full.residual_mps.max()
