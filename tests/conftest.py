"""Shared test setup: headless plotting, and every test's MLflow, Optuna and DVC state in its own temporary folder.

``isolated_state`` (autouse) points each test at a fresh folder (see ``state_isolation.py``): the project
root ``WORKBENCH_HOME``, the MLflow store, MLflow's default artifact root, Optuna's default journal folder and
DVC's site cache and config. A module- or session-scoped fixture that sets up its own project (for instance
``tests/learn/conftest.py``'s ``project``) keeps it: the per-test folder is only used where the session's
default is still in force. Session-scoped fixtures get a session folder. Each folder links ``pipelines/`` to
the repository's parameter files (read them, never write them), so ``project_root() / "pipelines/..."`` and
relative parameter paths resolve as in the repository; any other repository file a test needs it reads through
``state_isolation.REPO`` (this checkout).

At the end of the run the repository's ``mlflow.db``, ``mlartifacts/``, ``mlruns/`` and ``.optuna/`` are
compared with the start: a run that wrote to them fails, naming the files.
"""

import os
import sys
from pathlib import Path

import pytest
from state_isolation import CLEARED, REPO, isolated_env, pytest_sessionfinish, pytest_sessionstart  # noqa: F401

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
for _name in CLEARED:  # a developer's shell must not point the tests at a shared server or the demo's model
    os.environ.pop(_name, None)


@pytest.fixture(scope="session", autouse=True)
def _session_state(tmp_path_factory):
    """The session's default state folder (what session-scoped fixtures see)."""
    root = tmp_path_factory.mktemp("state-session")
    (root / "pipelines").symlink_to(REPO / "pipelines", target_is_directory=True)
    env = isolated_env(root)
    with pytest.MonkeyPatch.context() as mp:
        for k, v in env.items():
            mp.setenv(k, v)
        yield env


@pytest.fixture(autouse=True)
def isolated_state(_session_state, tmp_path_factory, monkeypatch):
    """This test's state folder (the project root ``WORKBENCH_HOME``); see the module's docstring."""
    keys = ("WORKBENCH_HOME", "MLFLOW_TRACKING_URI")
    if any(os.environ.get(k) != _session_state[k] for k in keys):
        yield Path(os.environ["WORKBENCH_HOME"])  # a wider fixture's own project: leave it in force
        return
    root = tmp_path_factory.mktemp("state")
    (root / "pipelines").symlink_to(REPO / "pipelines", target_is_directory=True)
    for k, v in isolated_env(root).items():
        monkeypatch.setenv(k, v)
    if "mlflow" in sys.modules:  # an earlier test may have set MLflow's process-wide URI to its own store
        sys.modules["mlflow"].set_tracking_uri(os.environ["MLFLOW_TRACKING_URI"])
    yield root


# The longest test files, longest first (`make test` durations, 25 Nov 2026): collected first, so that with
# `make test`'s two pytest-xdist workers (--dist loadfile, one file to one worker) they start at once and the
# short files fill the other worker, instead of a long file starting last and leaving one worker idle.
LONG_FILES = (
    "integration/test_campaign_walkthrough.py",
    "diagnose/test_diagnose_battery.py",
    "diagnose/test_servo_noref.py",
    "diagnose/test_diagnose_acceptance.py",
    "faults/test_kills_more.py",
)


def pytest_collection_modifyitems(session, config, items):
    """Long files first (stable: order inside a file and among the other files is kept)."""
    tests = Path(__file__).parent

    def rank(item) -> int:
        try:
            rel = Path(str(item.fspath)).resolve().relative_to(tests).as_posix()
        except ValueError:
            return len(LONG_FILES)
        return LONG_FILES.index(rel) if rel in LONG_FILES else len(LONG_FILES)

    items.sort(key=rank)
