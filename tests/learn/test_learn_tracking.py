"""Train through the CLI into a real MLflow sqlite store, register, reload in a fresh process, evaluate."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from learn_helpers import CONFIG, subprocess_env

from workbench.cli import main

#: the window length the project file configures (the runs must record it)
SEQ_LEN = int(yaml.safe_load(CONFIG.read_text())["train"]["data"]["seq_len"])

SHRINK = ["data.train_windows_per_epoch=1536", "data.batch_size=128", "model.hidden_size=16", "trainer.max_epochs=2",
          "trainer.max_time_s=null", "trainer.early_stop_patience=0"]


@pytest.fixture(scope="module")
def trained(project, parquet):
    interp, _ = parquet
    out = project / "datasets" / "models" / "fed-lstm"
    args = ["train", "--config", str(CONFIG), "--data", str(interp), "--out", str(out), "--dvc-stage", "train",
            "--quiet", "--register"]
    for s in SHRINK:
        args += ["--set", s]
    assert main(args) == 0
    return out


@pytest.mark.slow
def test_train_writes_model_folder_and_registers_champion(trained, project):
    from mlflow import MlflowClient

    assert {"model.json", "weights.pt", "split.json", "metrics.json", "config.json", "history.csv",
            "learning_curve.png"} <= {p.name for p in trained.iterdir()}
    client = MlflowClient()
    mv = client.get_model_version_by_alias("fed-lstm", "champion")
    run = client.get_run(mv.run_id)
    tags = run.data.tags
    assert tags["campaign"] == "synth" and tags["variant"] == "lstm" and tags["dvc_stage"] == "train"
    assert tags["kind"] == "train" and tags["git_commit"]
    assert run.data.params["model.dropout"] == "0.21" and run.data.params["data.seq_len"] == str(SEQ_LEN)
    curve = client.get_metric_history(run.info.run_id, "val_loss")
    assert [m.step for m in curve] == [1, 2]
    saved = json.loads((trained / "metrics.json").read_text())
    assert run.data.metrics["test_mse_fy_n"] == pytest.approx(saved["test_mse_fy_n"])
    # the model is an MLflow model of the run (MLmodel, signature) holding the model folder as its leg_model artifact
    assert "model/MLmodel" in {a.path for a in client.list_artifacts(run.info.run_id, "model")}
    import mlflow

    from workbench.learn.legmodel import mlflow_model_folder

    logged = mlflow_model_folder(Path(mlflow.artifacts.download_artifacts(f"runs:/{run.info.run_id}/model")))
    assert {"model.json", "weights.pt", "split.json"} <= {p.name for p in logged.iterdir()}
    assert run.data.tags["state"] == "complete" and run.data.tags["model_id"] == mv.source.removeprefix("models:/")


@pytest.mark.slow
def test_registered_model_reproduces_its_test_metric_in_a_fresh_process(trained, project, parquet):
    interp, _ = parquet
    code = f"""
import json, sys
from workbench.hydro.legmodel import load_leg_model
from workbench.learn.evaluate import evaluate_models
from workbench.learn.split import ParameterSplit
from workbench.learn.windows import read_table
m = load_leg_model("lstm")
split = ParameterSplit.from_dict(json.load(open({str(trained / 'split.json')!r})))
metrics, _ = evaluate_models(read_table([{str(interp)!r}]), split, {{"lstm": m}})
print(json.dumps({{"run_id": m.info["run_id"], "uri": m.info["model_uri"], "mse": metrics["lstm"]["mse"]}}))
"""
    # loading reads the store and writes nothing into it (MLflow's models:/ download of a local store
    # wrote a registered_model_meta file into the logged model's own folder)
    def store_files() -> dict:
        return {p: p.stat().st_mtime_ns for p in project.rglob("*") if p.is_file() and p.suffix != ".db"
                and "datasets" not in p.parts}

    before = store_files()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=subprocess_env(project),
                         cwd=project, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    after = store_files()
    assert after == before, sorted(str(p) for p in set(after) ^ set(before) | {p for p in before if after.get(p) != before[p]})
    from mlflow import MlflowClient

    logged = MlflowClient().get_run(got["run_id"]).data.metrics
    assert got["uri"] == "models:/fed-lstm@champion"
    for ch, v in got["mse"].items():
        assert v == pytest.approx(logged[f"test_mse_{ch}"], rel=1e-6)


@pytest.mark.slow
def test_evaluate_writes_the_contract_metrics_and_figures(trained, project, parquet, tmp_path):
    interp, measured = parquet
    out, figs = tmp_path / "metrics" / "leg_models.json", tmp_path / "figs"
    # the interpolated file: interpolated rows must not enter any metric
    assert main(["evaluate", "--config", str(CONFIG), "--data", str(interp), "--split", str(trained / "split.json"),
                 "--out", str(out), "--figures", str(figs), "--dvc-stage", "evaluate"]) == 0
    m = json.loads(out.read_text())
    channels = ["fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm"]
    assert {"ef", "lstm"} <= set(m)
    for name in ("ef", "lstm"):
        assert list(m[name]["mse"]) == channels and list(m[name]["r2"]) == channels
        assert list(m[name]["mse_by_flow_speed"]) == ["0.10", "0.20"]  # measured speeds only, no 0.15
        assert all(list(v) == channels for v in m[name]["mse_by_flow_speed"].values())
        assert m[name]["by_parameter_set"] and all(np.isfinite(v) for v in m[name]["mse"].values())
    split = json.loads((trained / "split.json").read_text())
    n_test_sets = split["counts"]["test"]
    assert m["lstm"]["n_runs"] == m["ef"]["n_runs"] == 2 * n_test_sets
    assert m["lstm"]["n_ticks"] == m["ef"]["n_ticks"] == 2 * n_test_sets * (390 - (SEQ_LEN - 1))
    assert {p.name for p in figs.iterdir()} == {"prediction_a.png", "prediction_b.png", "mse_boxplot.png"}
    # the same numbers from the measured-only file
    out2 = tmp_path / "again.json"
    assert main(["evaluate", "--config", str(CONFIG), "--data", str(measured), "--split", str(trained / "split.json"),
                 "--out", str(out2), "--no-mlflow"]) == 0
    assert json.loads(out2.read_text())["lstm"]["mse"] == m["lstm"]["mse"]
    from mlflow import MlflowClient

    exp = MlflowClient().get_experiment_by_name("evaluate")
    runs = MlflowClient().search_runs([exp.experiment_id], "tags.kind = 'evaluate'")
    assert len(runs) == 1 and runs[0].data.metrics["ef_mse_fy_n"] == pytest.approx(m["ef"]["mse"]["fy_n"])
    assert runs[0].data.tags["dvc_stage"] == "evaluate"


@pytest.mark.slow
def test_champion_falls_back_to_the_local_folder(trained, project, capsys):
    from workbench.errors import ModelError
    from workbench.learn.registry import load_champion

    m = load_champion(alias="no-such-alias")
    assert m.info["model_uri"].endswith("fed-lstm")
    assert "using the local model folder" in capsys.readouterr().err
    with pytest.raises(ModelError, match="no trained LSTM"):
        load_champion(alias="no-such-alias", fallback=project / "empty")


def test_bad_input_is_one_line(project, parquet, capsys, tmp_path):
    interp, _ = parquet
    assert main(["train", "--config", str(CONFIG), "--data", str(interp), "--set", "model.colour=red"]) == 2
    err = capsys.readouterr().err  # the key path and the keys allowed there
    assert "train.model.colour: unknown setting 'colour'" in err and "allowed: variant, hidden_size" in err
    assert main(["train", "--config", str(CONFIG), "--data", str(tmp_path / "none.parquet"), "--no-mlflow"]) == 2
    assert "processed data file not found" in capsys.readouterr().err
    assert main(["evaluate", "--config", str(CONFIG), "--data", str(interp), "--split", str(tmp_path / "s.json"),
                 "--out", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "split file not found" in err and err.count("\n") == 1
    assert not (tmp_path / "m.json").exists()


@pytest.mark.slow
def test_an_ad_hoc_train_run_registers_nothing_unless_asked(trained, project, parquet):
    """The README tour trains a quick model: the champion alias must stay where the pipeline put it."""
    import mlflow

    interp, _ = parquet
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{project / 'mlflow.db'}")
    before = client.get_model_version_by_alias("fed-lstm", "champion").version
    n_before = len(client.search_model_versions("name='fed-lstm'"))
    args = ["train", "--config", str(CONFIG), "--data", str(interp), "--out", str(project / "scratch" / "quick"),
            "--quiet"]
    for s in SHRINK:
        args += ["--set", s]
    assert main(args) == 0
    assert client.get_model_version_by_alias("fed-lstm", "champion").version == before
    assert len(client.search_model_versions("name='fed-lstm'")) == n_before
    assert (project / "scratch" / "quick" / "weights.pt").is_file()
