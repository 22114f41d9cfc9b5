"""The virtual pool swims gait files to convergence and refuses a trajectory that did not converge."""

import json

import numpy as np
import pytest
import yaml

from workbench.errors import ConvergenceError, SettingError
from workbench.virtual_lab.pool import PoolSettings, simulated_trials


def _gait_files(folder):
    folder.mkdir()
    gaits = {"straight": {"theta_h_min_deg": -20.0, "theta_k_max_deg": -50.0, "frequency_hz": 0.5,
                          "alpha_rad": [0.0, 0.0, 3.14, 3.14]},
             "turn": {"theta_h_min_deg": 10.0, "theta_k_max_deg": -80.0, "frequency_hz": 0.65,
                      "alpha_rad": [0.0, 3.14, 0.0, 3.14]}}
    for task, params in gaits.items():
        doc = {"task": task, "model": "ef", "solutions": [
            {"rank": 1, "params": params, "objectives": {"f1": 0.0, "f2": 0.0, "f3": 60.0}, "score": 1.0}]}
        (folder / f"{task}-ef.json").write_text(json.dumps(doc))
    return folder


def test_pool_swims_converged_trajectories(tmp_path):
    gaits = _gait_files(tmp_path / "gaits")
    s = PoolSettings(models=("ef",), best=1, physics="ef")
    trials = simulated_trials(gaits, s)
    assert [t.id for t in trials] == ["ef-straight-1", "ef-turn-1"]
    straight = trials[0]
    assert straight.t_s[-1] >= 60.0 and straight.y_m[-1] > 1.0       # swam on over the whole cap


def test_pool_refuses_an_unconverged_trajectory_naming_the_gait_file_and_solution(tmp_path):
    gaits = _gait_files(tmp_path / "gaits")
    robot = yaml.safe_load(open("pipelines/robot.yaml"))
    robot["simulation"].update(max_iter=2, tol_mps=1e-9)
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(robot))
    s = PoolSettings(models=("ef",), best=1, physics="ef", robot_params=str(tmp_path / "robot.yaml"))
    with pytest.raises(ConvergenceError) as err:
        simulated_trials(gaits, s)
    msg = str(err.value)
    assert "\n" not in msg
    assert str(gaits / "straight-ef.json") in msg and "solution rank 1" in msg and "did not converge" in msg
    residual = float(msg.split("residual ")[1].split(" m/s")[0])
    assert np.isfinite(residual) and residual > 1e-9


def test_pool_names_the_gait_file_and_solution_of_a_bad_gait_value(tmp_path):
    gaits = _gait_files(tmp_path / "gaits")
    doc = json.loads((gaits / "turn-ef.json").read_text())
    doc["solutions"][0]["params"]["frequency_hz"] = 0.0           # a setting no gait can swim with
    (gaits / "turn-ef.json").write_text(json.dumps(doc))
    with pytest.raises(SettingError) as err:                        # a parameter fault, not a contract fault
        simulated_trials(gaits, PoolSettings(models=("ef",), best=1, physics="ef"))
    assert err.value.path == str(gaits / "turn-ef.json") and err.value.where == "solution rank 1 of turn-ef"
    assert "positive frequency" in str(err.value) and "\n" not in str(err.value)
