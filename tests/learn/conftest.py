"""Fixtures of the learn tests: a small processed-format campaign, the real config shrunk, an isolated project."""

from __future__ import annotations

import pytest
from learn_helpers import make_frame


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
