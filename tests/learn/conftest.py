"""Fixtures of the learn tests: a small processed-format campaign, the real config shrunk, an isolated project."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from learn_synthetic import make_frame

CONFIG = Path(__file__).resolve().parents[2] / "pipelines" / "learn.yaml"


@pytest.fixture(scope="session")
def frame():
    """12 parameter sets x 2 measured speeds + 1 interpolated speed, 3 cycles at 0.5 Hz (390 ticks a run)."""
    return make_frame(interpolated_speeds=(0.15,))


@pytest.fixture(scope="session")
def parquet(tmp_path_factory, frame):
    """(interpolated file, measured-only file) in a session folder."""
    import polars as pl

    d = tmp_path_factory.mktemp("processed")
    interp, measured = d / "synth-interp.parquet", d / "synth.parquet"
    frame.write_parquet(interp)
    frame.filter(~pl.col("interpolated")).write_parquet(measured)
    return interp, measured


def tiny_config(paths, root: Path, **over):
    """The real pipelines/learn.yaml train section, shrunk to a few CPU batches, tracked in ``root``."""
    from workbench.learn.config import load_config

    base = {"data.paths": [str(p) for p in paths], "data.train_windows_per_epoch": 1536, "data.batch_size": 128,
            "model.hidden_size": 16, "trainer.max_epochs": 2, "trainer.max_time_s": None,
            "trainer.early_stop_patience": 0, "tracking.tracking_uri": f"sqlite:///{root / 'mlflow.db'}",
            "model_dir": str(root / "datasets" / "models" / "fed-lstm")}
    base.update(over)
    return load_config(CONFIG).with_overrides(base)


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """An isolated project root (WORKBENCH_HOME) with its own MLflow store, for one test module."""
    root = tmp_path_factory.mktemp("project")
    (root / "pyproject.toml").write_text("")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("WORKBENCH_HOME", str(root))
        mp.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{root / 'mlflow.db'}")
        mp.delenv("WORKBENCH_LSTM_URI", raising=False)
        mp.delenv("DVC_STAGE", raising=False)
        yield root


def subprocess_env(root: Path) -> dict:
    """Environment of a fresh process in the isolated project."""
    env = dict(os.environ)
    env.update(WORKBENCH_HOME=str(root), MLFLOW_TRACKING_URI=f"sqlite:///{root / 'mlflow.db'}", MPLBACKEND="Agg")
    return env
