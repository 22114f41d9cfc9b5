"""Issue 15.3: one tracking module. A trained model is an MLflow model (pyfunc-loadable, registered through MLflow),
runs are named apart (DVC stage vs manual), every parameter is logged, runs carry a state, and a copied project logs
into its own folder. A real sqlite store in a temporary project; real (tiny) torch training on the virtual lab's data.
"""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from learn_helpers import tiny_config


@pytest.fixture(scope="module")
def trained(project, parquet):
    """A DVC-stage training run registered as fed-lstm@champion (``train --register --dvc-stage train``).

    ``train(cfg)`` writes nothing; its model card is written as the command does.
    """
    from workbench.commands.train import write_model_card
    from workbench.learn.train import train

    interp, _ = parquet
    cfg = tiny_config([interp], project, **{"tracking.register": True, "tracking.dvc_stage": "train"})
    metrics, objects = train(cfg)
    write_model_card(cfg.model_dir, objects["card"])
    return cfg, metrics, objects


def _client(project):
    from mlflow import MlflowClient

    return MlflowClient(tracking_uri=f"sqlite:///{project / 'mlflow.db'}")


@pytest.mark.slow
def test_the_registered_champion_is_an_mlflow_model_that_predicts_as_the_workbench_model(trained, project, parquet):
    import mlflow
    import polars as pl

    from workbench.hydro.legmodel import load_leg_model
    from workbench.learn.windows import motion_of_run, read_table

    cfg, _metrics, objects = trained
    client = _client(project)
    mv = client.get_model_version_by_alias("fed-lstm", "champion")
    run = client.get_run(objects["run_id"])
    # the registry links version, logged model and run (what the UI's Models column shows)
    assert mv.run_id == objects["run_id"] and mv.source == f"models:/{objects['model_id']}"
    assert [o.model_id for o in run.outputs.model_outputs] == [objects["model_id"]]
    assert run.data.tags["model_id"] == objects["model_id"]

    mlflow.set_tracking_uri(f"sqlite:///{project / 'mlflow.db'}")
    pyfunc = mlflow.pyfunc.load_model("models:/fed-lstm@champion")
    names = pyfunc.metadata.get_input_schema().input_names()
    assert names[:5] == ["flow_speed_mps", "theta_h_deg", "theta_k_deg", "omega_h_dps", "omega_k_dps"]
    assert pyfunc.metadata.get_output_schema().input_names() == ["fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm"]
    assert (Path(pyfunc.metadata.artifact_path.removeprefix("file://")) / "input_example.json").is_file()

    # two measured runs of the processed table, as a user would pass them (extra columns ignored)
    _, measured = parquet
    frame = pl.read_parquet(measured)
    first, second = frame["run_id"].unique(maintain_order=True).to_list()[:2]
    df = frame.filter(pl.col("run_id").is_in([first, second])).to_pandas()
    got = pyfunc.predict(df)
    assert list(got.columns) == ["fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm"] and len(got) == len(df)

    # the workbench's own prediction: the model folder by path (what DVC stages load), run by run
    table = read_table([measured])
    ids = table.runs["run_id"].to_list()
    by_path = load_leg_model(cfg.model_dir)
    for rid in (first, second):
        want = by_path.wrench(motion_of_run(table, ids.index(rid)))[0]
        rows = (df["run_id"] == rid).to_numpy()
        np.testing.assert_allclose(got.to_numpy()[rows], want, rtol=1e-6, atol=1e-9)
    # and the workbench's registry loader reads the same registered version
    by_alias = load_leg_model("lstm")
    assert by_alias.describe()["model_version"] == str(mv.version)
    r = ids.index(first)
    np.testing.assert_allclose(by_alias.wrench(motion_of_run(table, r))[0], by_path.wrench(motion_of_run(table, r))[0])


@pytest.mark.slow
def test_a_dvc_stage_run_and_a_manual_run_are_named_apart(trained, project, parquet):
    from workbench.learn.train import train

    interp, _ = parquet
    _cfg, _m, staged = trained
    quick = tiny_config([interp], project, **{"trainer.max_epochs": 1, "data.train_windows_per_epoch": 256,
                                               "model_dir": None})
    _m2, manual = train(quick, log_model=False, score_test=False)
    client = _client(project)
    a, b = client.get_run(staged["run_id"]), client.get_run(manual["run_id"])
    assert a.info.run_name != b.info.run_name
    commit = a.data.tags["git_commit"]
    short = commit[:7] if commit != "unknown" else "nogit"
    assert a.info.run_name == f"dvc:train fed-lstm synth @{short}"
    assert b.info.run_name == f"train fed-lstm synth @{short}"
    assert (a.data.tags["dvc_stage"], b.data.tags["dvc_stage"]) == ("train", "manual")
    assert a.data.tags["state"] == b.data.tags["state"] == "complete"


@pytest.mark.slow  # 5.5 s of CPU idle (29 Nov 2026)
def test_every_parameter_is_logged_and_a_long_value_is_marked(project):
    from workbench.tracking import TRUNCATED, run_tags, tracked_run

    long_value = "x" * 7000
    params = {"grid": {f"cell{i:03d}": i * 0.5 for i in range(230)}, "note": long_value, "nested": {"a": {"b": [1, 2]}}}
    with tracked_run(name="params test", tags=run_tags(kind="test", campaigns=["synth"]), experiment="tracking-test",
                     params=params) as run:
        pass
    client = _client(project)
    got = client.get_run(run.info.run_id).data.params
    assert len(got) == 232  # 230 + note + nested.a.b: nothing cut at MLflow's 100 per call
    assert got["grid.cell229"] == "114.5" and got["nested.a.b"] == "[1, 2]"
    assert got["note"].endswith(TRUNCATED) and len(got["note"]) == 6000
    doc = json.loads(Path(client.download_artifacts(run.info.run_id, "params.json")).read_text())
    assert doc["note"] == long_value and doc["grid"]["cell000"] == 0.0
    assert client.get_run(run.info.run_id).data.tags["state"] == "complete"


# slow (docs/testing.md): 5.7 s alone, 7.9 s of CPU (measured 29 Nov 2026)
@pytest.mark.slow
def test_a_diagnosis_logs_every_setting(project, tmp_path):
    """diagnose (and gait) hand their settings to workbench.tracking: more than 100 are all logged (once cut at 100)."""
    import dataclasses

    from mlflow import MlflowClient

    from workbench.diagnose.tracking import log_trajectory_diagnosis

    Settings = dataclasses.make_dataclass("Settings", [(f"knob{i:03d}", float, i * 0.25) for i in range(150)])
    out = tmp_path / "out"
    out.mkdir()
    (out / "trajectory_errors.json").write_text("{}\n")
    doc = {"trials": str(tmp_path / "pool-a"), "gaits": "g", "reference": "r", "wall_margin_m": 0.1, "models": {}}
    run_id = log_trajectory_diagnosis(doc, {}, out, Settings(), f"sqlite:///{project / 'mlflow.db'}")
    params = MlflowClient(f"sqlite:///{project / 'mlflow.db'}").get_run(run_id).data.params
    assert sum(k.startswith("settings.knob") for k in params) == 150 and params["settings.knob149"] == "37.25"


@pytest.mark.slow
def test_a_copied_project_logs_into_its_own_folder(trained, project, tmp_path, monkeypatch):
    import mlflow

    from workbench.hydro.legmodel import load_leg_model
    from workbench.project import setup_mlflow

    copy = tmp_path / "copied-project"
    shutil.copytree(project, copy)
    orig_files = sorted(p for p in (project / "mlartifacts").rglob("*") if p.is_file())
    monkeypatch.setenv("WORKBENCH_HOME", str(copy))
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{copy / 'mlflow.db'}")
    # a fresh process in the copy loads the champion from the copy's files, the original's out of reach
    hidden = project / "mlartifacts.hidden"
    (project / "mlartifacts").rename(hidden)
    try:
        code = ("from workbench.hydro.legmodel import load_leg_model; "
                "print(load_leg_model('lstm').describe()['model_version'])")
        env = {**os.environ, "WORKBENCH_HOME": str(copy), "MLFLOW_TRACKING_URI": f"sqlite:///{copy / 'mlflow.db'}"}
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=copy,
                             timeout=300)
        assert out.returncode == 0 and out.stdout.split()[-1] == "1", out.stderr[-2000:]
        assert "was copied or moved" in out.stderr
    finally:
        hidden.rename(project / "mlartifacts")
    note = tmp_path / "note.txt"
    note.write_text("logged from the copy\n")
    setup_mlflow(None, "fed-lstm")  # what every verb does first
    with mlflow.start_run(run_name="from the copy") as run:
        mlflow.log_artifact(str(note))
    where = Path(mlflow.get_run(run.info.run_id).info.artifact_uri.removeprefix("file://"))
    assert where.is_relative_to(copy / "mlartifacts") and (where / "note.txt").is_file()
    assert sorted(p for p in (project / "mlartifacts").rglob("*") if p.is_file()) == orig_files  # original untouched
    # every stored path of the copy now names the copy's own files
    with sqlite3.connect(copy / "mlflow.db") as con:
        paths = [r[0] for q in ("SELECT artifact_location FROM experiments WHERE name != 'Default'",
                                "SELECT artifact_uri FROM runs", "SELECT artifact_location FROM logged_models",
                                "SELECT storage_location FROM model_versions") for r in con.execute(q)]
    assert paths and all(p.startswith((copy / "mlartifacts").as_uri()) for p in paths), paths
    # the champion registered in the original loads from the copy's files, with the original's out of reach
    hidden = project / "mlartifacts.hidden"
    (project / "mlartifacts").rename(hidden)
    try:
        assert Path(mlflow.artifacts.download_artifacts("models:/fed-lstm@champion")).is_relative_to(copy)
        model = load_leg_model("lstm")
        assert model.describe()["model_version"] == "1"
        assert len(mlflow.pyfunc.load_model("models:/fed-lstm@champion").predict(_frame())) == 40
    finally:
        hidden.rename(project / "mlartifacts")


def _frame():
    import pandas as pd

    t = np.arange(40) / 65.0
    return pd.DataFrame({"flow_speed_mps": 0.1, "theta_h_deg": -40 + 30 * np.sin(t), "theta_k_deg": 20 * np.cos(t),
                         "omega_h_dps": 30 * np.cos(t), "omega_k_dps": -20 * np.sin(t), "time_s": t})
