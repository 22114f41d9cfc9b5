"""Where a test's MLflow, Optuna and DVC state goes, and the check that the repository's own state was left alone.

The root conftest points every test at a fresh folder (:func:`isolated_env`): the workbench's project root
(``WORKBENCH_HOME``: default Optuna journals in ``.optuna/``, MLflow artifacts in ``mlartifacts/``), the
MLflow store (``MLFLOW_TRACKING_URI``, a sqlite file), MLflow's default artifact root for experiments that
MLflow creates itself (else ``./mlruns`` in the working directory) and DVC's site cache and config folders.
At the end of the session it compares :func:`snapshot` of the repository's stores with the one taken at the
start and fails the run when a test wrote to them (:func:`changes`): the hooks below, which the root conftest
imports (and ``pytest -p state_isolation`` loads, as ``tests/test_isolation.py`` does on a stand-in repository
named by ``WORKBENCH_TEST_REPO``).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

#: this checkout (tests that need the repository's files read them from here, not from ``project_root()``)
REPO = Path(__file__).resolve().parent.parent
#: the folder whose state the session-end check guards (the checkout unless a test names a stand-in)
GUARDED_ROOT = Path(os.environ.get("WORKBENCH_TEST_REPO") or REPO)
#: the repository's own state, which no test may write
GUARDED = ("mlflow.db", "mlartifacts", "mlruns", ".optuna")
#: variables that would point a test at shared state: a developer's MLflow server or project, a DVC stage
CLEARED = ("MLFLOW_TRACKING_URI", "MLFLOW_REGISTRY_URI", "MLFLOW_EXPERIMENT_NAME", "MLFLOW_EXPERIMENT_ID",
           "MLFLOW_RUN_ID", "WORKBENCH_HOME", "WORKBENCH_LSTM_URI", "DVC_STAGE", "DVC_EXP_NAME", "DVC_ROOT")
#: MLflow's (private) default artifact root of a store the client opens; unset, it is ./mlruns
MLFLOW_DEFAULT_ARTIFACTS = "_MLFLOW_SERVER_ARTIFACT_ROOT"


def isolated_env(root: Path) -> dict[str, str]:
    """Environment variables that keep the workbench's, MLflow's, Optuna's and DVC's state under ``root``."""
    root = Path(root)
    return {
        "WORKBENCH_HOME": str(root),
        "MLFLOW_TRACKING_URI": f"sqlite:///{root / 'mlflow.db'}",
        MLFLOW_DEFAULT_ARTIFACTS: str(root / "mlruns"),
        "DVC_SITE_CACHE_DIR": str(root / "dvc-site-cache"),
        "DVC_GLOBAL_CONFIG_DIR": str(root / "dvc-global"),
        "DVC_SYSTEM_CONFIG_DIR": str(root / "dvc-system"),
        "DVC_NO_ANALYTICS": "1",
    }


def snapshot(repo: Path) -> dict[str, tuple[int, int]]:
    """Relative path -> (size, mtime in ns) of every file under the guarded paths of ``repo``."""
    out: dict[str, tuple[int, int]] = {}
    for name in GUARDED:
        top = Path(repo) / name
        if top.is_file():
            st = top.stat()
            out[name] = (st.st_size, st.st_mtime_ns)
            continue
        for folder, _, files in os.walk(top):
            for f in files:
                p = Path(folder) / f
                try:
                    st = p.stat()
                except FileNotFoundError:
                    continue
                out[str(p.relative_to(repo))] = (st.st_size, st.st_mtime_ns)
    return out


def changes(before: dict[str, tuple[int, int]], after: dict[str, tuple[int, int]]) -> list[str]:
    """Human-readable list of the files added, removed or changed between two snapshots."""
    added = sorted(set(after) - set(before))
    removed = sorted(set(before) - set(after))
    changed = sorted(k for k in set(before) & set(after) if before[k] != after[k])
    return [f"added {k}" for k in added] + [f"removed {k}" for k in removed] + [f"changed {k}" for k in changed]


def pytest_sessionstart(session):
    session.config._wb_repo_state = snapshot(GUARDED_ROOT)


def pytest_sessionfinish(session, exitstatus):
    before = getattr(session.config, "_wb_repo_state", None)
    if before is None or hasattr(session.config, "workerinput"):
        return
    touched = changes(before, snapshot(GUARDED_ROOT))
    if not touched:
        return
    shown = "\n  ".join(touched[:20]) + (f"\n  ... and {len(touched) - 20} more" if len(touched) > 20 else "")
    msg = f"ERROR: tests wrote to the repository's MLflow/Optuna state in {GUARDED_ROOT} (isolation broken):\n  {shown}"
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None:
        reporter.write_line("")
        reporter.write_line(msg, red=True, bold=True)
    else:
        print(msg, file=sys.stderr)
    session.exitstatus = pytest.ExitCode.TESTS_FAILED
