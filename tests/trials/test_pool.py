"""The virtual pool writes a contract trials folder with ground truth, deterministically."""

import json

import numpy as np
import pytest
from trials_helpers import SMALL, fast_straight, truth_of

from workbench.contract.trials import load_trials
from workbench.errors import ContractError
from workbench.trials.video import probe_video
from workbench.virtual_lab.pool import (
    PoolSettings,
    TiltedCamera,
    generate_pool,
    read_gait_file,
    simulated_trials,
    true_scores,
)


def test_folder_follows_the_contract(small_pool):
    folder, per_trial = load_trials(small_pool)
    assert not per_trial
    s = PoolSettings(**SMALL, seed=3)
    assert folder.tank.width_m == 4.0 and folder.tank.length_m == 5.0
    corners = np.array(folder.camera.reference_m)
    expected = TiltedCamera.looking_at(s).project(corners)
    assert np.allclose(folder.camera.reference_px, expected, atol=0.01)
    assert {t.model for t in folder.trials} == {"EF", "FED-LSTM"}
    truth = truth_of(small_pool)
    for t in folder.trials:
        info = probe_video(t.video)
        assert (info.width, info.height, info.fps) == (480, 270, 15.0)
        frames = truth[t.id]["frames"]["video_time_s"]
        assert info.n_frames == len(frames)
        assert t.start_s == pytest.approx(0.53)
        assert truth[t.id]["scores"]["completed"] is True


def test_truth_scores_use_the_contract_definitions():
    # a straight path drawn exactly: 2 m at 0.2 m/s along the start heading, tilted in the tank
    t = np.arange(0, 20, 0.01)
    yaw0 = np.radians(25)
    fwd = np.array([-np.sin(yaw0), np.cos(yaw0)])
    right = np.array([np.cos(yaw0), np.sin(yaw0)])
    p = np.array([1.0, 1.0]) + np.outer(0.2 * t, fwd) + np.outer(0.02 * 0.2 * t, right)
    sc = true_scores("straight", t, p[:, 0], p[:, 1], np.full_like(t, yaw0))
    assert sc["time_s"] == pytest.approx(10.0, abs=0.05)
    assert sc["mae_x_m"] == pytest.approx(0.02, abs=1e-3)  # X = 0.02 Y, stations average Y = 1 m
    assert sc["completed"] and sc["radius_m"] is None


def test_rendering_is_deterministic(tmp_path):
    s = PoolSettings(**{**SMALL, "seed": 9, "occlusion_fraction": 1.0})
    short = fast_straight("a", video_until_s=2.0)
    a = generate_pool(tmp_path / "a", [short], settings=s, progress=False)
    b = generate_pool(tmp_path / "b", [short], settings=s, progress=False, workers=2)
    assert (a / "videos" / "a.mp4").read_bytes() == (b / "videos" / "a.mp4").read_bytes()
    assert (a / "truth.json").read_text() == (b / "truth.json").read_text()
    assert len(truth_of(a)["a"]["occlusions_video_s"]) == 1


def _gait_file(folder, task, model, n=2, fixed=None):
    sols = [{"rank": r, "params": {"theta_h_min_deg": -20.0 - 5 * r, "theta_k_max_deg": -50.0, "frequency_hz": 0.5,
                                   "alpha_rad": [0.0, 3.14, 3.14, 0.0]},
             "objectives": {"f1": 0.0, "f2": 0.0, "f3": 0.0}, "score": float(r)} for r in (2, 1)][:n]
    doc = {"task": task, "model": model, "solutions": sols}
    if fixed:
        doc["fixed"] = fixed
    (folder / f"{task}-{model}.json").write_text(json.dumps(doc))


def test_simulated_trials_from_gait_files(tmp_path):
    _gait_file(tmp_path, "straight", "ef")
    s = PoolSettings(models=("ef",), tasks=("straight",), best=1, physics="ef", robot_params="/nonexistent.yaml")
    trials = simulated_trials(tmp_path, s)
    assert [t.id for t in trials] == ["ef-straight-1"]
    tr = trials[0]
    assert (tr.model, tr.solution, tr.task, tr.gait_hz) == ("EF", 1, "straight", 0.5)
    assert tr.t_s[0] == 0.0 and tr.t_s[-1] > 60.0
    assert tr.x_m[0] == 0.0 and tr.y_m[0] == 0.0
    # the simulator's world frame is the start frame: this symmetric gait swims forward (+y)
    assert tr.y_m[-1] > 0.05


def test_gait_files_with_different_fixed_constants_simulate_apart(tmp_path):
    _gait_file(tmp_path, "straight", "ef", fixed={"phi_rad": 1.0472, "theta_h_max_deg": -100.0})
    _gait_file(tmp_path, "straight", "lstm", fixed={"phi_rad": 0.5, "theta_h_max_deg": -90.0})
    s = PoolSettings(models=("ef", "lstm"), tasks=("straight",), best=1, physics="ef",
                     robot_params="/nonexistent.yaml")
    trials = simulated_trials(tmp_path, s)
    assert [t.id for t in trials] == ["ef-straight-1", "lstm-straight-1"]
    assert [t.model for t in trials] == ["EF", "FED-LSTM"]
    # same gait parameters, different fixed constants: different swims
    assert not np.allclose(trials[0].y_m, trials[1].y_m)


def test_gait_file_errors(tmp_path):
    with pytest.raises(ContractError, match="gait file not found"):
        read_gait_file(tmp_path / "straight-ef.json")
    (tmp_path / "bad.json").write_text(json.dumps({"solutions": [{"params": {}}]}))
    with pytest.raises(ContractError, match="rank"):
        read_gait_file(tmp_path / "bad.json")
    s = PoolSettings(models=("ef",), tasks=("turn",), best=1)
    with pytest.raises(ContractError, match="turn-ef.json"):
        simulated_trials(tmp_path, s)


def test_settings_refuse_unknown_keys():
    from workbench.errors import ParamsError

    with pytest.raises(ParamsError, match=r"^p\.yaml, pool\.fsp: unknown setting 'fsp' \(did you mean 'fps'\? allowed: trials_id"):
        PoolSettings.from_mapping({"fsp": 30}, source="p.yaml")
    with pytest.raises(ParamsError, match=r"pool\.head_marker: marker colour 'orange' is not one of red"):
        PoolSettings.from_mapping({"head_marker": "orange"})
    with pytest.raises(ParamsError, match=r"pool\.camera_position_m: must be a list of 3 values"):
        PoolSettings.from_mapping({"camera_position_m": [1.0, 2.0]})
