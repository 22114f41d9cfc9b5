"""`workbench optimize --model FOLDER --label NAME` (issue 14.6, 15.1): a saved model by path, results named by label,
and `--model lstm` printing and recording the registry version it resolved to, which is the same model as the folder."""

import json

import numpy as np
import pytest
import yaml
from models import small_lstm

from workbench.cli import main


def _params(tmp_path):
    """The real pipelines/gait.yaml, shrunk: 8 x 2 NSGA-II, 4 s swims, two gaits checked directly."""
    doc = yaml.safe_load(open("pipelines/gait.yaml", encoding="utf-8"))
    opt = doc["optimize"]
    opt["nsga2"].update(pop_size=8, n_gen=2)
    opt["tasks"]["straight"].update(cap_s=4.0, finish_distance_m=0.15, hv_reference=[0.5, 1.0, 5.0])
    opt.update(retain=2, verify_direct=2)
    path = tmp_path / "gait.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    """A small FED-LSTM (16-tick windows, random weights) saved as `workbench train` saves one."""
    from workbench.learn.legmodel import save_model

    folder = tmp_path_factory.mktemp("models") / "fed-lstm-16"
    folder.mkdir()
    model = small_lstm(seed=3, hidden=16)
    model.info = {"campaigns": ["synth"], "git_commit": "0" * 40}
    save_model(model, folder)
    return folder


@pytest.fixture()
def registry(tmp_path, saved, monkeypatch):
    """An isolated project whose MLflow store holds `saved` as fed-lstm version 1 (alias champion)."""
    import mlflow

    from workbench.learn.tracking import register_model

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    monkeypatch.delenv("WORKBENCH_LSTM_URI", raising=False)
    mlflow.set_tracking_uri(uri)
    mlflow.set_experiment("fed-lstm")
    with mlflow.start_run() as run:
        mlflow.log_artifacts(str(saved), artifact_path="model")
        version = register_model(run, "fed-lstm", "champion")
    yield uri, version, run.info.run_id
    mlflow.set_tracking_uri(None)   # leave no process-wide store behind for other tests


@pytest.mark.slow
def test_a_model_folder_loads_by_path_and_predicts_as_the_registered_version(saved, registry):
    from workbench.hydro.legmodel import load_leg_model
    from workbench.hydro.motion import JointSinusoid

    uri, version, run_id = registry
    by_path = load_leg_model(str(saved))
    by_alias = load_leg_model("lstm")
    by_uri = load_leg_model(f"models:/fed-lstm/{version}")
    js = JointSinusoid.from_params(dict(theta_h_min_deg=-20.0, theta_h_max_deg=-100.0, theta_k_min_deg=80.0,
                                        theta_k_max_deg=-40.0, frequency_hz=0.5, phi_rad=1.0472, alpha_rad=0.3))
    motion = js.motion(np.arange(200) / 65.0, 0.12)
    w = by_path.wrench(motion)
    assert np.abs(w).max() > 1e-3  # a real prediction, not zeros
    np.testing.assert_array_equal(by_alias.wrench(motion), w)
    np.testing.assert_array_equal(by_uri.wrench(motion), w)
    assert by_path.seq_len == 16 and by_path.describe()["model_path"] == str(saved)
    d = by_alias.describe()
    assert d["model_version"] == version and d["run_id"] == run_id and d["model_uri"] == "models:/fed-lstm@champion"
    # model.json itself names the folder too
    assert load_leg_model(str(saved / "model.json")).seq_len == 16


def test_a_folder_that_is_no_model_is_refused_in_one_line(tmp_path, capsys):
    params = _params(tmp_path)
    empty = tmp_path / "not-a-model"
    empty.mkdir()
    rc = main(["optimize", "--task", "straight", "--model", str(empty), "--params", str(params),
               "--out", str(tmp_path / "g"), "--no-mlflow"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and err[-1].startswith("error:") and "unknown leg force model" in err[-1] and str(empty) in err[-1]
    torn = tmp_path / "torn"
    torn.mkdir()
    (torn / "model.json").write_text(json.dumps({"schema": "workbench/learned-leg-model@1", "model": {}}))
    rc = main(["optimize", "--task", "straight", "--model", str(torn), "--params", str(params),
               "--out", str(tmp_path / "g"), "--no-mlflow"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and err[-1].startswith("error:") and len(err[-1]) < 400
    assert not (tmp_path / "g").exists()


def test_bad_label_is_refused_before_any_work(tmp_path, saved, capsys):
    rc = main(["optimize", "--task", "straight", "--model", str(saved), "--label", "../x", "--params",
               str(_params(tmp_path)), "--out", str(tmp_path / "g"), "--no-mlflow"])
    err = capsys.readouterr().err
    assert rc == 2 and "error: --label: '../x' is not a file-name-safe name" in err and not (tmp_path / "g").exists()


@pytest.mark.slow
def test_optimize_by_path_with_label_and_by_alias_give_the_same_gaits(tmp_path, saved, registry, capsys):
    import mlflow

    uri, version, run_id = registry
    params = _params(tmp_path)
    out = tmp_path / "gaits"
    assert main(["optimize", "--task", "straight", "--model", str(saved), "--label", "lstm16", "--params",
                 str(params), "--out", str(out), "--tracking-uri", uri]) == 0
    err = capsys.readouterr().err
    assert f"model folder {saved}" in err
    doc = json.loads((out / "straight-lstm16.json").read_text())
    assert doc["model"] == "lstm16" and doc["model_spec"] == str(saved)
    assert doc["model_source"]["model_path"] == str(saved) and "model_version" not in doc["model_source"]
    assert doc["model_description"]["seq_len"] == 16
    metrics = json.loads((out / "straight-lstm16.metrics.json").read_text())
    assert metrics["model"] == "lstm16" and metrics["model_source"]["model_path"] == str(saved)
    ctrl = json.loads((out / "straight-lstm16" / "controller.json").read_text())
    assert ctrl["model"] == "lstm16"
    assert {p.name for p in out.iterdir() if not p.name.startswith(".")} == {  # hidden: the set's record
        "straight-lstm16.json", "straight-lstm16.metrics.json", "straight-lstm16"}

    # the registry alias, as people use it: the version is printed and recorded
    out2 = tmp_path / "gaits-alias"
    assert main(["optimize", "--task", "straight", "--model", "lstm", "--params", str(params), "--out", str(out2),
                 "--tracking-uri", uri]) == 0
    err = capsys.readouterr().err
    assert f"registered model fed-lstm version {version}" in err and run_id in err
    doc2 = json.loads((out2 / "straight-lstm.json").read_text())
    assert doc2["model"] == "lstm" and doc2["model_source"]["model_version"] == version
    assert doc2["model_source"]["model_uri"] == "models:/fed-lstm@champion"
    assert json.loads((out2 / "straight-lstm.metrics.json").read_text())["model_source"]["model_version"] == version
    # the same model: the same search finds the same gaits with the same objectives
    assert [s["params"] for s in doc2["solutions"]] == [s["params"] for s in doc["solutions"]]
    assert [s["objectives"] for s in doc2["solutions"]] == [s["objectives"] for s in doc["solutions"]]

    mlflow.set_tracking_uri(uri)
    client = mlflow.MlflowClient()
    runs = client.search_runs([client.get_experiment_by_name("optimize").experiment_id])
    tags = {r.data.tags["model"]: r.data.tags for r in runs}
    assert tags["lstm16"]["model_path"] == str(saved) and tags["lstm16"]["model_spec"] == str(saved)
    assert tags["lstm"]["model_version"] == version and tags["lstm"]["model_run_id"] == run_id
    assert tags["lstm"]["model_uri"] == "models:/fed-lstm@champion"


def test_default_label_of_a_folder_is_its_name(saved):
    from workbench.gait.export import model_label

    assert model_label(str(saved)) == "fed-lstm-16" == model_label(str(saved / "model.json"))
    assert (model_label("ef"), model_label("lstm"), model_label("models:/fed-lstm@tuned")) == \
        ("ef", "lstm", "fed-lstm-tuned")
    assert model_label("no/such/folder") == "no-such-folder"   # not a path on disk: the spec as before
