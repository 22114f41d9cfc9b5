"""Several machines tune one study: Optuna on PostgreSQL, MLflow server on PostgreSQL (issue: scale-out).

Two independent `workbench tune` processes (standing in for two machines) share one Optuna
study in a real PostgreSQL server and log to one MLflow server whose backend is PostgreSQL and
which serves the artifacts. Afterwards the study has exactly the trials asked for, with unique
numbers, MLflow holds one trial run per Optuna trial, and the registry's ``tuned`` alias names the
study's best trial. Registering one model from many machines at the same moment (the race the
two workers' ends once lost in CI) succeeds everywhere.
"""

import json
import os
import shutil
import subprocess
import sys
import threading
import urllib.request
from pathlib import Path

import pytest
from itest_servers import create_database, mlflow_server, postgres_server

pytestmark = pytest.mark.slow

PROJECT = Path(__file__).resolve().parents[2]
STUDY = "scale-out-itest"
TRIALS_PER_MACHINE = 2


def _post(url, body):
    req = urllib.request.Request(url, data=json.dumps(body).encode(), headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.loads(r.read())


def test_two_workers_share_a_postgres_study_and_one_mlflow_server(small_processed, tmp_path):
    import optuna

    with postgres_server(tmp_path / "pg") as base:
        optuna_url = create_database(base, "optuna")
        mlflow_db = create_database(base, "mlflow")
        with mlflow_server(mlflow_db, tmp_path / "artifacts") as server:
            procs = []
            for machine in ("a", "b"):
                home = tmp_path / f"machine-{machine}"
                (home / "pipelines").mkdir(parents=True)
                shutil.copy(PROJECT / "pipelines" / "learn.yaml", home / "pipelines" / "learn.yaml")
                cmd = [sys.executable, "-m", "workbench.cli", "tune", "--data", str(small_processed),
                       "--study", STUDY, "--storage", optuna_url, "--tracking-uri", server,
                       "--n-trials", str(TRIALS_PER_MACHINE), "--workers", "1", "--out", str(home / "tune"),
                       "--set", "trainer.max_epochs=1", "--set", "data.train_windows_per_epoch=512",
                       "--set", "trainer.max_time_s=60",
                       # two "machines" on one machine's cores: one thread each, not two each
                       "--set", "trainer.torch_threads=1"]
                env = {**os.environ, "WORKBENCH_HOME": str(home), "MLFLOW_TRACKING_URI": server}
                log = open(home / "tune.log", "w")
                procs.append((subprocess.Popen(cmd, cwd=home, env=env, stdout=log, stderr=subprocess.STDOUT),
                              home / "tune.log"))
            for p, log in procs:
                assert p.wait(timeout=900) == 0, log.read_text()[-3000:]

            study = optuna.load_study(study_name=STUDY, storage=optuna_url)
            numbers = [t.number for t in study.trials]
            assert len(numbers) == 2 * TRIALS_PER_MACHINE
            assert sorted(numbers) == list(range(2 * TRIALS_PER_MACHINE))  # none lost, none duplicated
            finished = {optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED}
            assert all(t.state in finished for t in study.trials)

            runs = []
            token = None
            exps = _post(f"{server}/api/2.0/mlflow/experiments/search", {"max_results": 100})["experiments"]
            while True:
                body = {"experiment_ids": [e["experiment_id"] for e in exps], "max_results": 500,
                        "filter": f"tags.study = '{STUDY}'"}
                if token:
                    body["page_token"] = token
                page = _post(f"{server}/api/2.0/mlflow/runs/search", body)
                runs += page.get("runs", [])
                token = page.get("next_page_token")
                if not token:
                    break
            trial_tags = [{t["key"]: t["value"] for t in r["data"].get("tags", [])} for r in runs]
            trial_numbers = sorted(int(t["trial"]) for t in trial_tags if t.get("kind") == "trial")
            assert trial_numbers == list(range(2 * TRIALS_PER_MACHINE)), trial_tags

            # the alias the workers set names the study's best trial, registered once
            import mlflow
            from mlflow import MlflowClient

            mlflow.set_tracking_uri(server)
            client = MlflowClient()
            best_run = study.best_trial.user_attrs["mlflow_run_id"]
            assert client.get_model_version_by_alias("fed-lstm", "tuned").run_id == best_run
            assert len(client.search_model_versions(f"name = 'fed-lstm' and run_id = '{best_run}'")) == 1

            # many machines registering and aliasing at the same instant: every one succeeds
            _register_all_at_once(client, [r for r in trial_tags if r.get("kind") == "trial"], runs)


def _register_all_at_once(client, trial_tags, runs, n_threads=8):
    from workbench.learn.tracking import register_model

    run_objs = [client.get_run(r["info"]["run_id"]) for r in runs
                if {t["key"]: t["value"] for t in r["data"].get("tags", [])}.get("kind") == "trial"]
    assert run_objs, trial_tags
    barrier = threading.Barrier(n_threads)
    errors, versions = [], []

    def one(i):
        barrier.wait()
        try:
            versions.append(register_model(run_objs[i % len(run_objs)], "race-model", "race"))
        except Exception as exc:  # noqa: BLE001 - collected and asserted below
            errors.append(repr(exc))

    threads = [threading.Thread(target=one, args=(i,)) for i in range(n_threads)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not errors, errors
    assert len(versions) == n_threads
    alias = client.get_model_version_by_alias("race-model", "race")
    assert alias.version in versions
    for run in run_objs:  # each run registered once, whoever got there first
        assert len(client.search_model_versions(f"name = 'race-model' and run_id = '{run.info.run_id}'")) == 1
