"""What the paper's gait space can and cannot do about turning, and the per-side extension that can."""

import json
import math

import numpy as np
import pytest

from workbench.errors import ParamsError
from workbench.gait.config import OptimizeSettings, TaskSettings, config_from_dict
from workbench.gait.objectives import TaskSpec
from workbench.gait.optimize import optimize_task
from workbench.gait.run import NSGA2Settings
from workbench.gait.space import GaitSpace
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.simulator import GaitBatch, legs_to_body, simulate

EF = EmpiricalFormula()


def _cycle_mean_yaw_torque(gaits, robot, flow_mps, n=400):
    """Cycle-mean yaw torque (N m) of each gait's four legs at a constant flow: one period, n even samples."""
    out = []
    for i in range(len(gaits)):
        g = gaits.rows(i)
        t = np.arange(n) / (n * g.frequency_hz[0])
        motion = g.leg_motion(t)
        m = type(motion)(motion.dt_s, motion.theta_h_deg, motion.theta_k_deg, motion.omega_h_dps,
                         motion.omega_k_dps, np.full_like(motion.theta_h_deg, flow_mps), motion.alpha_h_dps2,
                         motion.alpha_k_dps2)
        w = legs_to_body(robot, EF.wrench(m).reshape(1, 4, n, 6))
        out.append((w[0, :, :, 5].sum(axis=0).mean(), np.abs(w[0, :, :, 5].mean(axis=1)).max()))
    return np.array(out)


def test_paper_space_has_no_mean_yaw_torque_at_constant_flow_but_per_side_ranges_do(robot):
    rng = np.random.default_rng(4)
    paper = GaitSpace()
    tz = _cycle_mean_yaw_torque(paper.gaits(paper.sample(12, rng)), robot, flow_mps=0.08)
    # each leg's mean torque is not small (the legs' own), but left and right cancel exactly whatever the phases
    assert np.all(tz[:, 1] > 1e-4)
    assert np.all(np.abs(tz[:, 0]) < 1e-5 * tz[:, 1].max())           # (sampling of one cycle: 1e-6)
    side = GaitSpace(extension="per_side_range")
    x = side.sample(12, rng)
    x[:, 0], x[:, 1] = -50.0, 10.0                    # left legs stroke 60 deg further than right legs
    tz_side = _cycle_mean_yaw_torque(side.gaits(x), robot, flow_mps=0.08)
    assert np.all(np.abs(tz_side[:, 0]) > 1e-3)


@pytest.mark.slow
def test_paper_gaits_turn_slowly_and_a_per_side_gait_turns_both_ways(robot):
    rng = np.random.default_rng(0)
    paper = GaitSpace()
    tr = simulate(paper.gaits(paper.sample(24, rng)), EF, robot, duration_s=40.0)
    assert tr.converged.all()
    rate = np.abs(np.degrees(tr.yaw_rate_rps[:, -650:].mean(axis=1)))        # the last 10 s
    assert np.median(rate) < 4.0                                             # a 360 deg turn takes > 90 s
    side = GaitSpace(extension="per_side_range")
    g = side.gaits([[10.0, -50.0, -20.0, -80.0, 0.6, 0.0, 0.0, math.pi, math.pi]])
    both = simulate(GaitBatch.from_arrays(
        np.vstack([g.theta_h_min_deg, g.mirrored().theta_h_min_deg]),
        np.vstack([g.theta_k_max_deg, g.mirrored().theta_k_max_deg]), [0.6, 0.6],
        np.vstack([g.alpha_rad, g.mirrored().alpha_rad])), EF, robot, duration_s=40.0)
    assert both.converged.all()
    r = np.degrees(both.yaw_rate_rps[:, -650:].mean(axis=1))
    assert abs(r[0]) > rate.max() and abs(r[0]) > 15.0                      # 360 deg in under 25 s
    assert r[0] * r[1] < 0 and abs(r[0] + r[1]) < 1e-6 * abs(r[0])


def test_per_side_range_round_trips_through_the_gait_and_controller_files(robot):
    space = GaitSpace(extension="per_side_range")
    x = space.sample(5, np.random.default_rng(1))
    np.testing.assert_allclose(space.vectors(space.gaits(x)), np.column_stack([x[:, :5], np.mod(x[:, 5:], 2 * np.pi)]))
    with pytest.raises(ValueError, match="one per side"):
        space.vectors(GaitBatch.from_arrays([[-20, -20, -30, -20]], -50, 0.5, [0, 0, 0, 0]))
    spec = TaskSpec("turn", cap_s=5.0, target_yaw_deg=20.0)
    cfg = OptimizeSettings(tasks={"turn": TaskSettings(spec, (3.0, 1.0, 6.0))}, space=space,
                         nsga2=NSGA2Settings(pop_size=8, n_gen=2, seed=0), retain=3)
    out = optimize_task(cfg, "turn", EF, robot, model_label="ef", plots=False)
    doc = json.loads(json.dumps(out.gait_doc))
    assert doc["gait_space"] == "per_side_range" and out.controller_doc["gait_space"] == "per_side_range"
    sol = doc["solutions"][0]["params"]
    th = sol["theta_h_min_deg"]
    assert isinstance(th, list) and th[0] == th[2] and th[1] == th[3]        # LF = LH, RF = RH
    again = simulate(GaitBatch.from_params([s["params"] for s in doc["solutions"]]), EF, robot, duration_s=5.0)
    np.testing.assert_allclose(again.yaw_rad, out.trajectories.yaw_rad, atol=1e-12)
    joints = out.controller_doc["gaits"][0]["joints"]
    assert joints["LF"]["hfe"]["amplitude_deg"] == pytest.approx(abs(-100.0 - th[0]) / 2)
    assert joints["RF"]["hfe"]["amplitude_deg"] == pytest.approx(abs(-100.0 - th[1]) / 2)
    # the settings file names it; a typo is refused
    assert config_from_dict({"space": {"extension": "per_side_range"}}).space.extension == "per_side_range"
    with pytest.raises(ParamsError, match=r"^g\.yaml, optimize\.space: space\.extension must be one of"):
        config_from_dict({"space": {"extension": "per_leg_everything"}}, "g.yaml")
