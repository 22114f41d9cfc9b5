"""`workbench train --registered-model fed-lstm-16` (issue 14.6): the 16-tick model gets its own registered model and
champion; the 32-tick champion stays where it was; the folder and the registered version are the same model."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from learn_helpers import CONFIG

from workbench.cli import main

SHRINK = ["data.train_windows_per_epoch=1536", "data.batch_size=128", "model.hidden_size=16", "trainer.max_epochs=1",
          "trainer.max_time_s=null", "trainer.early_stop_patience=0"]


@pytest.mark.slow
def test_sixteen_tick_model_registers_under_its_own_name(project, parquet, tmp_path, capsys):
    import mlflow
    from mlflow import MlflowClient

    from workbench.hydro.legmodel import load_leg_model
    from workbench.hydro.motion import JointSinusoid
    from workbench.learn.tracking import register_model

    interp, _ = parquet
    # a 32-tick champion already registered (any run with a model/ artifact)
    placeholder = tmp_path / "placeholder"
    placeholder.mkdir()
    (placeholder / "model.json").write_text(json.dumps({"schema": "workbench/learned-leg-model@1"}))
    mlflow.set_tracking_uri(os.environ["MLFLOW_TRACKING_URI"])   # the isolated project's store
    mlflow.set_experiment("fed-lstm")
    with mlflow.start_run() as run:
        mlflow.log_artifacts(str(placeholder), artifact_path="model")
        before = register_model(run, "fed-lstm", "champion")

    out = project / "datasets" / "models" / "fed-lstm-16"
    args = ["train", "--config", str(CONFIG), "--data", str(interp), "--out", str(out), "--quiet",
            "--set", "data.seq_len=16", "--registered-model", "fed-lstm-16", "--register"]
    for s in SHRINK:
        args += ["--set", s]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "registered fed-lstm-16 version 1 as @champion" in err

    client = MlflowClient()
    assert str(client.get_model_version_by_alias("fed-lstm", "champion").version) == before   # untouched
    mv = client.get_model_version_by_alias("fed-lstm-16", "champion")
    assert str(mv.version) == "1" and client.get_run(mv.run_id).data.params["data.seq_len"] == "16"
    by_alias, by_path = load_leg_model("models:/fed-lstm-16@champion"), load_leg_model(str(out))
    assert by_alias.seq_len == by_path.seq_len == 16
    js = JointSinusoid.from_params(dict(theta_h_min_deg=-30.0, theta_h_max_deg=-100.0, theta_k_min_deg=80.0,
                                        theta_k_max_deg=-40.0, frequency_hz=0.5, phi_rad=1.0472, alpha_rad=0.0))
    motion = js.motion(np.arange(120) / 65.0, 0.2)
    np.testing.assert_array_equal(by_alias.wrench(motion), by_path.wrench(motion))
    assert by_alias.describe()["model_version"] == "1" and by_path.describe()["model_path"] == str(out)
