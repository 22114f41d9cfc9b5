"""`workbench optimize` end to end: files per the contract, the MLflow run, determinism, bad input."""

import json

import pytest
import yaml
from test_export import check_contract_gait_file

from workbench.cli import main


def _params(tmp_path, name="gait.yaml", **changes):
    doc = yaml.safe_load(open("pipelines/gait.yaml", encoding="utf-8"))
    opt = doc["optimize"]
    opt["nsga2"].update(pop_size=8, n_gen=3)
    opt["tasks"]["straight"].update(cap_s=4.0, finish_distance_m=0.15, hv_reference=[0.5, 1.0, 5.0])
    opt["tasks"]["turn"].update(cap_s=4.0, target_yaw_deg=20.0, hv_reference=[2.0, 1.0, 5.0])
    opt.update(changes)
    path = tmp_path / name
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


@pytest.mark.slow
def test_optimize_writes_contract_files_and_an_mlflow_run(tmp_path, capsys):
    params = _params(tmp_path)
    out = tmp_path / "gaits"
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    drag = tmp_path / "drag.json"  # a fit-drag result of towing campaign 'tow-a' (the paper's laws)
    drag.write_text(json.dumps({"forward": {"coefficients": [9.997, -0.132, 0.334]},
                                "lateral": {"coefficients": [26.1, -2.14, 0.0]},
                                "source": "datasets/processed/tow-a.parquet"}))
    rc = main(["optimize", "--task", "straight", "--model", "ef", "--params", str(params), "--out", str(out),
               "--tracking-uri", uri, "--drag", str(drag)])
    assert rc == 0
    doc = json.loads((out / "straight-ef.json").read_text())
    check_contract_gait_file(doc, "straight", "ef")
    assert len(doc["solutions"]) == yaml.safe_load(open(params))["optimize"]["retain"]
    assert doc["unconverged_gaits"] == 0 and doc["simulated_gaits"] >= 24 and doc["gait_space"] == "paper"
    assert all(s["converged"] for s in doc["solutions"])
    folder = out / "straight-ef"
    for name in ("controller.json", "best.csv", "history.csv", "population.csv"):
        assert (folder / name).stat().st_size > 0
    for name in ("pareto.png", "hypervolume.png", "trajectories.png"):
        assert (folder / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    metrics = json.loads((out / "straight-ef.metrics.json").read_text())
    assert metrics["evaluations"] == 24 and metrics["best_score"] == doc["solutions"][0]["score"]
    err = capsys.readouterr().err
    assert "gen   3/3" in err and "best S" in err and "HV" in err

    import mlflow

    mlflow.set_tracking_uri(uri)
    client = mlflow.MlflowClient()
    exp = client.get_experiment_by_name("optimize")
    (run,) = client.search_runs([exp.experiment_id])
    assert run.data.tags["task"] == "straight" and run.data.tags["model"] == "ef"
    assert run.data.tags["dvc_stage"] and run.data.tags["git_commit"]
    assert run.data.tags["campaign"] == "tow-a" and run.data.tags["kind"] == "optimize"
    hv = client.get_metric_history(run.info.run_id, "hypervolume")
    assert sorted(m.step for m in hv) == [1, 2, 3]
    assert sorted(m.step for m in client.get_metric_history(run.info.run_id, "unconverged")) == [1, 2, 3]
    assert run.data.metrics["final_unconverged_gaits"] == 0
    assert run.data.params["nsga2.pop_size"] == "8"
    arts = {a.path for a in client.list_artifacts(run.info.run_id)}
    assert {"straight-ef.json", "straight-ef", "best_table.json"} <= arts


@pytest.mark.slow
def test_same_seed_same_gait_file(tmp_path):
    params = _params(tmp_path)
    files = []
    for k in range(2):
        out = tmp_path / f"run{k}"
        assert main(["optimize", "--task", "turn", "--model", "ef", "--params", str(params), "--out", str(out),
                     "--no-mlflow", "--seed", "7"]) == 0
        files.append((out / "turn-ef.json").read_bytes())
        files.append((out / "turn-ef" / "controller.json").read_bytes())
    assert files[0] == files[2] and files[1] == files[3]
    assert json.loads(files[0])["seed"] == 7


@pytest.mark.slow  # 4.5 s of CPU idle (29 Nov 2026)
def test_bad_input_is_one_line_and_leaves_results_alone(tmp_path, capsys):
    params = _params(tmp_path)
    out = tmp_path / "gaits"
    assert main(["optimize", "--task", "straight", "--params", str(params), "--out", str(out), "--no-mlflow"]) == 0
    before = (out / "straight-ef.json").read_bytes()
    capsys.readouterr()
    bad = _params(tmp_path, "bad-gait.yaml", nsga2={"pop_size": 8, "n_gen": 3, "populaton": 5})
    assert main(["optimize", "--task", "straight", "--params", str(bad), "--out", str(out), "--no-mlflow"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "gait.yaml" in err and "populaton" in err and "\n" not in err
    assert main(["optimize", "--task", "straight", "--model", "no-such-model", "--params", str(params),
                 "--out", str(out), "--no-mlflow"]) == 2
    assert "no-such-model" in capsys.readouterr().err
    assert (out / "straight-ef.json").read_bytes() == before
