"""Trajectory level on the rich-truth virtual pool: a planted current or yaw drift is named, the clean pool is not.

The demo pool (datasets/raw/demo-pool, swum by the virtual lab's rich truth, rendered to video and
scored into datasets/scores/demo-pool) is copied; the test plants the effects into the copies'
tracked trajectories with its own formulas:

* a current (cx, cy) in the tank: tank position += c t; the trial-frame X, Y follow from the clean
  file's own tank <-> trial map (fitted here by least squares);
* a yaw drift r: the heading gains r t and the trial-frame velocity turns with it (integrated).

Rows from the clean track's first approach to a wall on are dropped (the pool robot was held by the
wall there; a planted drift would move a robot that did not move). The EF misses these trials by
metres, so the test is about the method separating what is fixed in the tank (a current) from the
model's own body-frame misfit, and a yaw drift from the base's heading with a reference session.
"""

import json
import shutil
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from workbench.commands.diagnose_trajectory import read_track_gaits, read_tracks
from workbench.diagnose.trajectory import (
    TrajectorySettings,
    diagnose_trajectories,
    errors_table,
    reference_tracks,
    simulate_tracks,
    trajectory_errors,
)

ROOT = Path(__file__).resolve().parents[2]
POOL = ROOT / "datasets" / "scores" / "demo-pool"
TANK = (4.0, 5.0)

pytestmark = pytest.mark.skipif(not (POOL / "scores.csv").is_file(), reason="demo pool not scored (dvc repro)")


def _copy(dst: Path, current=(0.0, 0.0), yaw_dps=0.0, noise=0.0, seed=0) -> Path:
    """A copy of the scored demo pool with a current and/or yaw drift planted by this test's formulas."""
    rng = np.random.default_rng(seed)
    (dst / "trajectories").mkdir(parents=True)
    shutil.copy(POOL / "scores.csv", dst / "scores.csv")
    summary = json.loads((POOL / "summary.json").read_text())
    summary["trials_dir"] = str(ROOT / "datasets" / "raw" / "demo-pool")
    (dst / "summary.json").write_text(json.dumps(summary))
    for f in sorted((POOL / "trajectories").glob("*.parquet")):
        df = pl.read_parquet(f)
        x, y = df["x_m"].to_numpy(), df["y_m"].to_numpy()
        wall = (x < 0.21) | (x > TANK[0] - 0.21) | (y < 0.21) | (y > TANK[1] - 0.21)
        keep = np.ones(len(df), bool)
        if wall.any():
            keep[int(np.argmax(wall)):] = False
        df = df.filter(pl.Series(keep))
        t = df["time_s"].to_numpy()
        tank = df.select(["x_m", "y_m"]).to_numpy()
        trial = df.select(["X_m", "Y_m"]).to_numpy()
        ok = np.isfinite(trial).all(1) & np.isfinite(tank).all(1)
        # the clean file's affine map trial -> tank (a rotation and the start position)
        a = np.c_[trial[ok], np.ones(ok.sum())]
        m = np.linalg.lstsq(a, tank[ok], rcond=None)[0]          # tank = [X, Y, 1] @ m
        tp = np.maximum(t, 0.0)
        heading = df["heading_change_deg"].to_numpy().copy()
        if yaw_dps:
            r = np.radians(yaw_dps)
            xy = trial.copy()
            post = (t >= 0) & ok
            tt, pp = t[post], trial[post]
            v = np.gradient(pp, tt, axis=0)
            ang = r * tt
            v = np.stack([np.cos(ang) * v[:, 0] - np.sin(ang) * v[:, 1],
                          np.sin(ang) * v[:, 0] + np.cos(ang) * v[:, 1]], 1)
            steps = 0.5 * (v[1:] + v[:-1]) * np.diff(tt)[:, None]
            xy[post] = pp[0] + np.vstack([[0.0, 0.0], np.cumsum(steps, 0)])
            trial = xy
            heading = heading + np.degrees(r * tp)
        tank = np.c_[trial, np.ones(len(t))] @ m + np.outer(tp, current)
        if noise:
            tank = tank + rng.normal(size=tank.shape) * noise
            heading = heading + rng.normal(size=heading.shape) * 20 * noise
        trial = np.linalg.lstsq(m[:2].T, (tank - m[2]).T, rcond=None)[0].T
        df = df.with_columns(pl.Series("x_m", tank[:, 0]), pl.Series("y_m", tank[:, 1]),
                             pl.Series("X_m", trial[:, 0]), pl.Series("Y_m", trial[:, 1]),
                             pl.Series("heading_change_deg", heading))
        df.write_parquet(dst / "trajectories" / f.name)
    return dst


@pytest.fixture(scope="module")
def ef_swims(tmp_path_factory):
    """The EF's swims of the demo pool's gaits (converged), shared by the tests."""
    from workbench.hydro.ef import EmpiricalFormula
    from workbench.hydro.robot import load_robot

    clean = _copy(tmp_path_factory.mktemp("clean") / "pool")
    tracks = read_tracks(clean)
    sims = simulate_tracks(tracks, read_track_gaits(ROOT / "datasets" / "gaits", tracks), EmpiricalFormula(),
                           load_robot(ROOT / "pipelines" / "robot.yaml"), TrajectorySettings())
    assert all(s.converged for s in sims)
    return clean, sims


def _named(d):
    return {e["name"]: e for e in d.effects}


@pytest.mark.slow
def test_clean_pool_with_the_ef_claims_nothing(ef_swims):
    clean, sims = ef_swims
    tracks = read_tracks(clean)
    err = trajectory_errors(tracks, sims)
    assert err["rms_position_m"] > 0.5                  # the EF is far off the rich truth's pool ...
    d = diagnose_trajectories(tracks, sims, "EF")
    assert d.effects == []                              # ... and that misfit is not mistaken for a current
    assert "yaw_drift" not in _named(d)


@pytest.mark.slow
@pytest.mark.parametrize("current", [(0.005, 0.0), (0.0, -0.015), (0.02, 0.02), (-0.03, 0.01)])
def test_planted_current_named_with_the_ef_as_base(tmp_path, ef_swims, current):
    _, sims = ef_swims
    tracks = read_tracks(_copy(tmp_path / "pool", current=current, noise=0.002))
    d = diagnose_trajectories(tracks, sims, "EF")
    named = _named(d)
    assert "current" in named and "yaw_drift" not in named
    got = np.array([named["current"]["params"]["cx_mps"], named["current"]["params"]["cy_mps"]])
    assert np.linalg.norm(got - current) <= 0.2 * np.linalg.norm(current)


@pytest.mark.slow
def test_planted_current_beside_a_yaw_drift(tmp_path, ef_swims):
    _, sims = ef_swims
    tracks = read_tracks(_copy(tmp_path / "pool", current=(0.01, -0.01), yaw_dps=1.5, noise=0.002))
    named = _named(diagnose_trajectories(tracks, sims, "EF"))
    got = np.array([named["current"]["params"]["cx_mps"], named["current"]["params"]["cy_mps"]])
    assert np.linalg.norm(got - (0.01, -0.01)) <= 0.2 * np.hypot(0.01, 0.01)


@pytest.mark.parametrize("yaw,current", [(0.5, (0.0, 0.0)), (-1.5, (0.0, 0.0)), (3.0, (0.0, 0.0)),
                                         (-1.0, (0.0, 0.015))])
def test_planted_yaw_drift_named_against_a_reference_session(tmp_path, yaw, current):
    ref = read_tracks(_copy(tmp_path / "ref"))
    tracks = read_tracks(_copy(tmp_path / "new", current=current, yaw_dps=yaw, noise=0.002, seed=3))
    d = diagnose_trajectories(tracks, reference_tracks(tracks, ref), "reference", base="ref")
    named = _named(d)
    assert named["yaw_drift"]["params"]["rate_dps"] == pytest.approx(yaw, rel=0.2)
    assert ("current" in named) == bool(np.any(current))
    if np.any(current):
        got = np.array([named["current"]["params"]["cx_mps"], named["current"]["params"]["cy_mps"]])
        assert np.linalg.norm(got - current) <= 0.2 * np.linalg.norm(current)


def test_clean_session_against_a_reference_claims_nothing(tmp_path):
    ref = read_tracks(_copy(tmp_path / "ref"))
    tracks = read_tracks(_copy(tmp_path / "new", noise=0.002, seed=5))
    d = diagnose_trajectories(tracks, reference_tracks(tracks, ref), "reference", base="ref")
    assert d.effects == [] and not [u for u in d.unexplained if u["kind"] == "heading_drift"]


def test_tracks_are_cut_at_the_wall():
    tracks = {tr.trial_id: tr for tr in read_tracks(POOL)}
    # the demo pool has trials that swim into the tank's side wall (held there by the pool: truth.json
    # clamped_at_wall); which ones depends on the demo's gaits, so the rule is checked on every track
    assert any(tr.cut_at_wall_s is not None for tr in tracks.values())
    for tid, tr in tracks.items():
        df = pl.read_parquet(POOL / "trajectories" / f"{tid}.parquet").filter(pl.col("time_s") >= 0)
        x, y = df["x_m"].to_numpy(), df["y_m"].to_numpy()
        near = (x < 0.25) | (x > TANK[0] - 0.25) | (y < 0.25) | (y > TANK[1] - 0.25)
        assert (tr.cut_at_wall_s is not None) == bool(near.any())
        assert tr.t_s[-1] < (tr.cut_at_wall_s if tr.cut_at_wall_s is not None else np.inf)


def test_errors_table_is_markdown():
    doc = {"models": {"EF": {"n_trials": 8, "excluded": [], "rms_position_m": 1.65, "rms_heading_deg": 80.0,
                             "mean_final_position_m": 2.0, "effects": []},
                      "augmented EF": {"n_trials": 7, "excluded": [{"trial_id": "x", "reason": "r"}],
                                       "rms_position_m": 0.25, "rms_heading_deg": 20.0,
                                       "mean_final_position_m": 0.3,
                                       "effects": [{"name": "current", "params": {"cx_mps": 0.01, "cy_mps": 0.0}}]}}}
    md = errors_table(doc)
    lines = md.strip().splitlines()
    assert lines[0].startswith("| model |") and len(lines) == 4
    assert "| EF | 8 | 1.650 | 80.0 | 2.000 | none | - |" in md
    assert "7 (1 unconverged, left out)" in md and "current (cx_mps +0.01, cy_mps +0)" in md


@pytest.mark.slow
def test_cli_models_side_by_side_and_mlflow(tmp_path):
    """The command: EF swims and a reference session, trajectory_errors.json/.png, one MLflow run (real sqlite store)."""
    from workbench.cli import main

    ref = _copy(tmp_path / "ref")
    new = _copy(tmp_path / "new", current=(0.0, 0.012), yaw_dps=-1.2, noise=0.002, seed=7)
    out = tmp_path / "out"
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    assert main(["diagnose", "--trials", str(new), "--reference", str(ref), "--models", "ef",
                 "--metrics", str(tmp_path / "metrics.json"),
                 "--gaits", str(ROOT / "datasets" / "gaits"), "--robot", str(ROOT / "pipelines" / "robot.yaml"),
                 "--out", str(out), "--tracking-uri", uri]) == 0
    doc = json.loads((out / "trajectory_errors.json").read_text())
    tracks = read_tracks(new)  # the session diagnosed (its planted current moves where trials meet the wall)
    n = len(tracks)
    assert list(doc["models"]) == ["EF"] and doc["models"]["EF"]["n_trials"] == n
    assert doc["models"]["EF"]["rms_position_m"] > 0.5
    assert set(doc["cut_at_wall"]) == {tr.trial_id for tr in tracks if tr.cut_at_wall_s is not None}
    diag = json.loads((out / "trajectory_diagnosis.json").read_text())
    named = {e["name"]: e["params"] for e in diag["effects"]}
    assert named["yaw_drift"]["rate_dps"] == pytest.approx(-1.2, rel=0.2)
    assert named["current"]["cy_mps"] == pytest.approx(0.012, rel=0.2)
    assert (out / "trajectory_errors.png").stat().st_size > 10_000
    assert f"| EF | {n} |" in errors_table(doc)
    metrics = json.loads((tmp_path / "metrics.json").read_text())["trajectory_error"]
    assert metrics["EF"]["rms_position_m"] == doc["models"]["EF"]["rms_position_m"]

    import mlflow

    mlflow.set_tracking_uri(uri)
    runs = mlflow.search_runs(experiment_names=["diagnose"], output_format="list")
    assert len(runs) == 1
    run = runs[0]
    assert run.data.tags["kind"] == "diagnose-trajectory"
    assert "reference:yaw_drift" in run.data.tags["effects"]
    assert run.data.metrics["rms_position_m.EF"] == pytest.approx(doc["models"]["EF"]["rms_position_m"])
    assert run.data.metrics["effect.reference.yaw_drift.rate_dps"] == pytest.approx(-1.2, rel=0.2)
    assert run.data.params["model.EF"] == "ef"
    arts = {a.path for a in mlflow.MlflowClient(uri).list_artifacts(run.info.run_id)}
    assert {"trajectory_errors.json", "trajectory_diagnosis.json", "trajectory_errors.png"} <= arts
