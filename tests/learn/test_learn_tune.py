"""Optuna search: two worker processes on one journal-backed study, every trial once, in MLflow; pruning = KILLED
and tagged state=pruned."""

from __future__ import annotations

import json

import pytest
import yaml
from learn_helpers import CONFIG

from workbench.cli import main


@pytest.fixture(scope="module")
def config(project):
    doc = yaml.safe_load(CONFIG.read_text())
    doc["train"]["data"].update(train_windows_per_epoch=1024, batch_size=128)
    doc["train"]["trainer"].update(max_time_s=None, early_stop_patience=0)
    doc["tune"].update(max_epochs=2, train_windows_per_epoch=1024)
    doc["tune"]["space"]["hidden_size"] = {"type": "categorical", "choices": [8, 16]}
    path = project / "learn.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.slow
def test_two_workers_share_one_study_without_lost_or_duplicated_trials(config, project, parquet):
    import optuna
    from mlflow import MlflowClient

    interp, _ = parquet
    out = project / "tune"
    assert main(["tune", "--config", str(config), "--data", str(interp), "--study", "s2", "--n-trials", "4",
                 "--workers", "2", "--out", str(out)]) == 0
    journal = project / ".optuna" / "s2.journal"
    study = optuna.load_study(study_name="s2", storage=optuna.storages.JournalStorage(
        optuna.storages.journal.JournalFileBackend(str(journal))))
    trials = study.get_trials()
    assert sorted(t.number for t in trials) == [0, 1, 2, 3]
    assert all(t.state.name in ("COMPLETE", "PRUNED") for t in trials)
    client = MlflowClient()
    exp = client.get_experiment_by_name("fed-lstm-tune")  # the tune section's experiment, apart from training
    parent = client.search_runs([exp.experiment_id], "tags.kind = 'tune'")
    assert len(parent) == 1 and parent[0].info.status == "FINISHED"
    children = client.search_runs([exp.experiment_id], "tags.kind = 'trial' and tags.study = 's2'")
    assert sorted(int(r.data.tags["trial"]) for r in children) == [0, 1, 2, 3]
    assert all(r.data.tags["mlflow.parentRunId"] == parent[0].info.run_id for r in children)
    assert {r.data.tags["worker"] for r in children} == {"0", "1"}  # both worker processes took part
    state = {t.number: t.state.name for t in trials}
    for r in children:
        assert r.info.status == {"COMPLETE": "FINISHED", "PRUNED": "KILLED"}[state[int(r.data.tags["trial"])]]
        assert r.data.tags["state"] == state[int(r.data.tags["trial"])].lower()
        assert r.info.run_name.startswith(f"trial {int(r.data.tags['trial']):03d} s2 synth @")
    best = json.loads((out / "best.json").read_text())["best"]
    assert best["number"] == study.best_trial.number and best["value"] == pytest.approx(study.best_value)
    assert client.get_model_version_by_alias("fed-lstm", "tuned").run_id == best["mlflow_run_id"]
    # the study survives: the same command again adds its trials to the same study
    assert main(["tune", "--config", str(config), "--data", str(interp), "--study", "s2", "--n-trials", "1",
                 "--workers", "1", "--no-mlflow"]) == 0
    assert sorted(t.number for t in study.get_trials()) == [0, 1, 2, 3, 4]


@pytest.mark.slow
def test_a_pruned_trial_ends_its_run_killed_and_tagged_pruned(config, project, parquet):
    import dataclasses

    import optuna
    from mlflow import MlflowClient

    from workbench.learn.config import load_config
    from workbench.learn.tune import TuneSettings, run_worker

    interp, _ = parquet
    base = load_config(config).with_overrides({"data.paths": [str(interp)]})
    doc = yaml.safe_load(config.read_text())["tune"]
    tune = dataclasses.replace(TuneSettings.from_dict(doc), study="pruned", pruner={"type": "threshold", "upper": 1e-9})
    storage = str(project / ".optuna" / "pruned.journal")
    (project / ".optuna").mkdir(exist_ok=True)  # the verb makes it; this test opens the journal itself
    optuna.create_study(study_name="pruned", storage=optuna.storages.JournalStorage(
        optuna.storages.journal.JournalFileBackend(storage)))
    run_worker({"config": base.to_dict(), "tune": dataclasses.asdict(tune), "storage": storage, "study": "pruned",
                "parent_run_id": None, "tracking_uri": None, "total": 1, "baseline": [], "worker": 0, "n_trials": 1})
    client = MlflowClient()
    exp = client.get_experiment_by_name("fed-lstm")
    runs = client.search_runs([exp.experiment_id], "tags.study = 'pruned'")
    assert len(runs) == 1 and runs[0].info.status == "KILLED"
    # MLflow's status cannot say "pruned": the run's state tag does (issue 15.3)
    assert runs[0].data.tags["state"] == "pruned" and "pruned" in runs[0].data.tags["state_detail"].lower()
