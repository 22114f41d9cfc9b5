"""Trajectory level on EF-made trials: a planted current is found and removed, a yaw drift reported.

The rich-truth pool battery is tests/diagnose/test_trajectory_pool.py."""

import json

import numpy as np
import polars as pl
import pytest

from workbench.commands.diagnose_trajectory import read_track_gaits, read_tracks
from workbench.diagnose.trajectory import TrajectorySettings, diagnose_trajectories, simulate_tracks
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.robot import RobotSettings
from workbench.hydro.simulator import GaitBatch, simulate

GAITS = [  # theta_h_min, theta_k_max, f, alpha (LF, RF, LH, RH)
    (-30.0, -60.0, 0.5, [0, np.pi, np.pi, 0]), (-10.0, -40.0, 0.6, [0, np.pi, 0, np.pi]),
    (-50.0, -80.0, 0.4, [0, 0, np.pi, np.pi]), (10.0, -20.0, 0.5, [0, 1.5, 3.1, 4.6]),
    (-20.0, -50.0, 0.55, [0, np.pi, np.pi, 0]),
]


def _write_trials(root, current=(0.0, 0.0), yaw_dps=0.0, seed=0):
    """Tracked trials made from the simulator plus planted effects (written independently of trajectory.py)."""
    rng = np.random.default_rng(seed)
    g = GaitBatch.from_arrays([a for a, *_ in GAITS], [b for _, b, *_ in GAITS], [f for _, _, f, _ in GAITS],
                              [al for *_, al in GAITS])
    tr = simulate(g, EmpiricalFormula(), RobotSettings(), duration_s=40.0)
    (root / "trajectories").mkdir(parents=True)
    gaits_dir = root / "gaits"
    gaits_dir.mkdir()
    doc = {"task": "straight", "model": "ef", "solutions": [
        {"rank": i + 1, "params": p} for i, p in enumerate(g.to_params())]}
    (gaits_dir / "straight-ef.json").write_text(json.dumps(doc))
    rows = []
    t_frame = np.arange(0, 40.0, 1 / 15)
    for i in range(len(GAITS)):
        t = tr.t_s
        v = np.gradient(np.stack([tr.x_m[i], tr.y_m[i]], 1), t, axis=0)
        a = np.radians(yaw_dps) * t
        v = np.stack([np.cos(a) * v[:, 0] - np.sin(a) * v[:, 1], np.sin(a) * v[:, 0] + np.cos(a) * v[:, 1]], 1)
        xy = np.vstack([[0, 0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t)[:, None], 0)])
        p = rng.uniform(0, 2 * np.pi)                       # the trial frame's heading in the tank
        right, head = np.array([np.sin(p), -np.cos(p)]), np.array([np.cos(p), np.sin(p)])
        tank = np.array([2.0, 2.5]) + xy[:, :1] * right + xy[:, 1:] * head + np.outer(t, current)
        tank = np.stack([np.interp(t_frame, t, tank[:, 0]), np.interp(t_frame, t, tank[:, 1])], 1)
        tank += rng.normal(size=tank.shape) * 0.004
        rel = tank - tank[0]
        trial = np.stack([rel @ right, rel @ head], 1)
        heading = np.interp(t_frame, t, tr.yaw_rad[i]) + np.radians(yaw_dps) * t_frame
        pl.DataFrame({"time_s": t_frame, "x_m": tank[:, 0], "y_m": tank[:, 1], "X_m": trial[:, 0], "Y_m": trial[:, 1],
                      "heading_change_deg": np.degrees(heading), "detected": np.ones(len(t_frame), bool),
                      "filled": np.zeros(len(t_frame), bool)}).write_parquet(root / "trajectories" / f"t{i}.parquet")
        rows.append({"trial_id": f"t{i}", "model": "EF", "solution": i + 1, "task": "straight", "time_s": 40.0,
                     "mae_x_m": 0.1, "radius_m": None, "completed": True})
    pl.DataFrame(rows).write_csv(root / "scores.csv")
    return root, gaits_dir


@pytest.mark.slow  # swims five gaits for 40 s: 15-23 s on the loaded 2-core machine
@pytest.mark.parametrize("current,yaw", [((0.03, -0.02), 0.0), ((0.0, 0.0), 1.5), ((0.02, 0.0), -1.0)])
def test_planted_current_and_yaw_drift_are_recovered(tmp_path, current, yaw):
    scores, gaits = _write_trials(tmp_path, current, yaw)
    tracks = read_tracks(scores)
    sims = simulate_tracks(tracks, read_track_gaits(gaits, tracks), EmpiricalFormula(), RobotSettings(),
                           TrajectorySettings())
    d = diagnose_trajectories(tracks, sims, "ef")
    names = {e["name"]: e for e in d.effects}
    assert ("current" in names) == bool(np.any(current))
    # without a reference session a steady yaw error is reported (it could be the model's), not claimed
    assert "yaw_drift" not in names
    heading = [u for u in d.unexplained if u["kind"] == "heading_drift"]
    assert bool(heading) == bool(yaw)
    if np.any(current):
        got = [names["current"]["params"]["cx_mps"], names["current"]["params"]["cy_mps"]]
        assert np.allclose(got, current, atol=0.2 * max(np.abs(current)))
    if yaw:
        assert heading[0]["rate_dps"] == pytest.approx(yaw, rel=0.2)
    j = d.to_json()
    if np.any(current) and not yaw:
        assert j["rms_position_error_m"]["after"] < 0.3 * j["rms_position_error_m"]["before"]


@pytest.mark.slow  # swims five gaits for 40 s: 15-23 s on the loaded 2-core machine
def test_nothing_claimed_when_the_simulator_is_right(tmp_path):
    scores, gaits = _write_trials(tmp_path)
    tracks = read_tracks(scores)
    sims = simulate_tracks(tracks, read_track_gaits(gaits, tracks), EmpiricalFormula(), RobotSettings(),
                           TrajectorySettings())
    d = diagnose_trajectories(tracks, sims, "ef")
    assert d.effects == [] and d.unexplained == []
    assert d.to_json()["rms_position_error_m"]["before"] < 0.02


@pytest.mark.slow  # swims five gaits for 40 s: 15-23 s on the loaded 2-core machine
def test_cli_trajectory_level(tmp_path):
    from workbench.cli import main

    scores, gaits = _write_trials(tmp_path / "in", (0.03, 0.0), 0.0)
    out = tmp_path / "out"
    assert main(["diagnose", "--trials", str(scores), "--gaits", str(gaits), "--model", "ef", "--out", str(out), "--no-mlflow"]) == 0
    doc = json.loads((out / "trajectory_diagnosis.json").read_text())
    assert [e["name"] for e in doc["effects"]] == ["current"]
    assert doc["rms_position_error_m"]["after"] < doc["rms_position_error_m"]["before"]
    assert (out / "trajectory_errors.png").stat().st_size > 1000


def test_cli_names_a_missing_gait_file_before_any_swim(tmp_path, capsys):
    """Bad input: the gait file a trial needs is not there -> one line naming it, exit 2, nothing written."""
    from workbench.cli import main

    scores = tmp_path / "scores"
    (scores / "trajectories").mkdir(parents=True)
    t = np.arange(0, 2.0, 0.1)
    pl.DataFrame({"time_s": t, "X_m": 0 * t, "Y_m": 0.05 * t, "heading_change_deg": 0 * t}).write_parquet(
        scores / "trajectories" / "t0.parquet")
    pl.DataFrame([{"trial_id": "t0", "model": "FED-LSTM-16", "solution": 1, "task": "turn"}]).write_csv(
        scores / "scores.csv")
    (tmp_path / "gaits").mkdir()
    out = tmp_path / "out"
    assert main(["diagnose", "--trials", str(scores), "--gaits", str(tmp_path / "gaits"), "--out", str(out),
                 "--no-mlflow"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(tmp_path / "gaits" / "turn-lstm16.json") in err[0] and "not found" in err[0]
    assert not out.exists()
