"""Sensitivity study (issue 14, part 4): factors reach the robot, convergence is checked, indices come out."""

import numpy as np
import pytest

from workbench.errors import ConvergenceError, SettingError
from workbench.gait.objectives import TaskSpec
from workbench.gait.sensitivity import FACTORS, Factor, robot_with, run_sensitivity
from workbench.hydro.legmodel import load_leg_model
from workbench.hydro.robot import RobotSettings
from workbench.hydro.simulator import GaitBatch

GAITS = GaitBatch.from_params([
    {"theta_h_min_deg": 9.4, "theta_k_max_deg": -23.2, "frequency_hz": 0.6, "alpha_rad": [5.95, 4.05, 3.32, 4.89]},
    {"theta_h_min_deg": -20.0, "theta_k_max_deg": -50.0, "frequency_hz": 0.5, "alpha_rad": [0.0, 3.1, 0.0, 3.1]},
    {"theta_h_min_deg": 0.0, "theta_k_max_deg": -30.0, "frequency_hz": 0.4, "alpha_rad": [0.0, 1.0, 2.0, 3.0]},
])


def test_robot_with_sets_the_constants_and_makes_low_speed_drag_linear():
    base = RobotSettings()
    r = robot_with(base, {"yaw_inertia_kgm2": 0.04, "extra_yaw_damping_nms": 0.01, "drag_linear_below_mps": 0.08})
    assert r.yaw_inertia_kgm2 == 0.04 and r.extra_yaw_damping_nms == 0.01
    c2, c1, _ = base.forward_drag.coefficients
    # in range the nominal law (drop_intercept: c2 v^2 + c1 v); below 0.08 m/s linear to zero through it
    assert r.forward_drag.magnitude(0.2) == pytest.approx(c2 * 0.04 + c1 * 0.2)
    assert r.forward_drag.magnitude(0.04) == pytest.approx((c2 * 0.0064 + c1 * 0.08) / 2)
    assert r.forward_drag.magnitude(0.0) == 0.0
    # the low end of the range is the nominal robot
    r0 = robot_with(base, {"drag_linear_below_mps": 0.001})
    v = np.linspace(0.002, 0.35, 50)
    assert np.allclose(r0.forward_drag.magnitude(v), base.forward_drag.magnitude(v))
    assert np.allclose(r0.lateral_drag.magnitude(v), base.lateral_drag.magnitude(v))
    assert r.added_mass_lateral_kg == base.added_mass_lateral_kg


@pytest.mark.slow
def test_sobol_study_finds_the_only_factor_that_matters():
    # two factors: yaw damping (moves a turn) and a dummy on the forward added mass over a range too
    # narrow to matter; the turn score must owe its variance to the damping
    factors = (Factor("extra_yaw_damping_nms", 0.0, 0.05, "N m s", "test"),
               Factor("added_mass_forward_kg", 0.2, 0.2001, "kg", "test"))
    spec = TaskSpec("turn", cap_s=3.0, target_yaw_deg=90.0)
    res = run_sensitivity(GAITS, ["a", "b", "c"], load_leg_model("ef"), RobotSettings(), spec, n=16,
                          settings={"dt_s": 1 / 65, "relaxation": 0.6}, factors=factors)
    assert res.scores.shape == (16 * 4, 3)
    assert not res.unconverged
    d = res.to_dict()
    for lab in ("a", "b", "c"):
        st = d["indices"][lab]["total_order"]
        assert st["extra_yaw_damping_nms"] > 0.7
        assert st["added_mass_forward_kg"] < 0.1
    assert -1.0 <= d["ranking"]["kendall_tau_min"] <= 1.0


def test_power_of_two_required():
    with pytest.raises(SettingError, match="power of 2"):
        run_sensitivity(GAITS, ["a", "b", "c"], load_leg_model("ef"), RobotSettings(), TaskSpec("turn", cap_s=1.0,
                        target_yaw_deg=90.0), n=6)


def test_a_nominal_swim_that_did_not_converge_is_a_convergence_error():
    # one fixed-point iteration per window cannot reach a residual of 1e-12 m/s: no score is a result
    with pytest.raises(ConvergenceError, match=r"nominal robot's simulation did not converge for a, b, c"):
        run_sensitivity(GAITS, ["a", "b", "c"], load_leg_model("ef"), RobotSettings(),
                        TaskSpec("turn", cap_s=1.0, target_yaw_deg=90.0), n=2,
                        settings={"max_iter": 1, "tol_mps": 1e-12})


def test_factor_ranges_contain_the_nominal_robot():
    base = RobotSettings()
    for f in FACTORS:
        if hasattr(base, f.name):  # drag_linear_below_mps: its low end is the nominal law (tested above)
            assert f.low <= getattr(base, f.name) <= f.high, f.name
    assert np.all([f.low < f.high for f in FACTORS])


def test_sensitivity_verb_writes_json_and_figure(tmp_path):
    import json

    from workbench.cli import main

    gaits = {"task": "turn", "model": "ef", "settings": {"task": {"task": "turn", "cap_s": 2.0, "target_yaw_deg": 20.0}},
             "solutions": [{"rank": k + 1, "params": p} for k, p in enumerate(GAITS.to_params())]}
    path = tmp_path / "turn-ef.json"
    path.write_text(json.dumps(gaits))
    out = tmp_path / "sens"
    assert main(["sensitivity", "--gaits", str(path), "--n", "2", "--out", str(out)]) == 0
    doc = json.loads((out / "sensitivity.json").read_text())
    assert doc["n_simulations"] == 2 * (len(FACTORS) + 2)
    assert len(doc["gaits"]) == 3 and set(doc["indices"]) == {*doc["gaits"], "ranking_kendall_tau"}
    assert (out / "sensitivity.png").read_bytes()[:4] == b"\x89PNG"


def test_sensitivity_verb_refuses_a_gaits_file_without_its_task(tmp_path, capsys):
    import json

    from workbench.cli import main

    path = tmp_path / "g.json"
    path.write_text(json.dumps({"solutions": [{"rank": 1, "params": GAITS.to_params()[0]}]}))
    assert main(["sensitivity", "--gaits", str(path), "--out", str(tmp_path / "o")]) == 2
    assert "settings.task" in capsys.readouterr().err
