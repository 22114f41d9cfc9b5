"""The root fixture keeps every test's MLflow, Optuna and DVC state out of the repository, and the
session-end check fails a run that wrote to the repository's stores."""

import os
import subprocess
import sys
from pathlib import Path

from state_isolation import REPO, changes, snapshot


def test_each_test_gets_its_own_project_store_journal_and_dvc_folders(isolated_state):
    from dvc.dirs import global_config_dir, site_cache_dir

    from workbench.project import mlflow_artifact_root, mlflow_tracking_uri, project_root

    root = Path(isolated_state)
    assert REPO not in (root, *root.parents)
    assert project_root() == root
    assert mlflow_tracking_uri() == f"sqlite:///{root / 'mlflow.db'}"
    assert mlflow_artifact_root() == (root / "mlartifacts").as_uri()
    # tune's default study journal is project_root()/.optuna/<study>.journal
    assert (project_root() / ".optuna").parent == root
    assert Path(site_cache_dir()).parent == root and Path(global_config_dir()).parent == root
    # the repository's parameter files are there to read (relative parameter paths resolve as in the repository)
    assert (root / "pipelines").resolve() == REPO / "pipelines"
    assert sorted(p.name for p in (root / "pipelines").glob("*.yaml")) == sorted(
        p.name for p in (REPO / "pipelines").glob("*.yaml"))
    for name in ("WORKBENCH_LSTM_URI", "DVC_STAGE", "DVC_EXP_NAME"):
        assert name not in os.environ


def test_snapshot_sees_a_store_written_added_or_removed(tmp_path):
    (tmp_path / "mlartifacts" / "1").mkdir(parents=True)
    (tmp_path / "mlartifacts" / "1" / "model.pt").write_bytes(b"weights")
    (tmp_path / ".optuna").mkdir()
    (tmp_path / ".optuna" / "study.journal").write_text("{}\n")
    (tmp_path / "mlflow.db").write_bytes(b"SQLite format 3\0")
    (tmp_path / "unrelated.txt").write_text("not guarded")
    before = snapshot(tmp_path)
    assert sorted(before) == [".optuna/study.journal", "mlartifacts/1/model.pt", "mlflow.db"]
    (tmp_path / "unrelated.txt").write_text("changed, but not a store")
    assert changes(before, snapshot(tmp_path)) == []

    with open(tmp_path / "mlflow.db", "ab") as fh:
        fh.write(b"one more page")
    (tmp_path / "mlruns" / "0").mkdir(parents=True)
    (tmp_path / "mlruns" / "0" / "meta.yaml").write_text("name: Default\n")
    (tmp_path / ".optuna" / "study.journal").unlink()
    assert changes(before, snapshot(tmp_path)) == ["added mlruns/0/meta.yaml", "removed .optuna/study.journal",
                                                   "changed mlflow.db"]


def test_a_run_that_writes_the_repositorys_store_fails(tmp_path):
    repo = tmp_path / "repo"
    repo.mkdir()
    (repo / "mlflow.db").write_bytes(b"SQLite format 3\0")
    (tmp_path / "test_leaky.py").write_text(
        "import os\n"
        "def test_fine():\n    pass\n"
        "def test_leaks():\n"
        "    with open(os.path.join(os.environ['WORKBENCH_TEST_REPO'], 'mlflow.db'), 'ab') as fh:\n"
        "        fh.write(b'a run logged to the wrong store')\n")
    env = {**os.environ, "WORKBENCH_TEST_REPO": str(repo),
           "PYTHONPATH": os.pathsep.join([str(Path(__file__).parent), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "state_isolation", "-p", "no:cacheprovider",
                          "--rootdir", str(tmp_path), str(tmp_path / "test_leaky.py")],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=120)
    assert "2 passed" in out.stdout, out.stdout + out.stderr
    assert out.returncode == 1, out.stdout + out.stderr
    assert "isolation broken" in out.stdout and "changed mlflow.db" in out.stdout
