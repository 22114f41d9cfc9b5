"""A trained leg model as an MLflow model: ``mlflow.pyfunc.load_model("models:/fed-lstm@champion").predict(df)``.

``workbench train`` logs its model folder (``model.json`` + ``weights.pt`` + the run's records)
with ``mlflow.pyfunc.log_model`` as the artifact ``leg_model`` of an MLflow model, with a
signature and an input example, so the MLflow UI lists it under Models and any MLflow client
can load and call it. MLflow builds the model from :mod:`workbench.learn.mlflow_entry` (models
from code: no pickled Python objects), which needs the ``workbench`` package importable where
the model is loaded.

**Input frame** (a pandas DataFrame; a processed tunnel table converted with ``.to_pandas()``
works as it is, other columns are ignored):

=================  ======  ============================================================
column             type    meaning
=================  ======  ============================================================
``flow_speed_mps`` double  flow speed (m/s), required
``theta_h_deg``    double  hip angle (deg), required
``theta_k_deg``    double  knee angle (deg), required
``omega_h_dps``    double  hip rate (deg/s), required
``omega_k_dps``    double  knee rate (deg/s), required
``time_s``         double  optional: the tick times; their median step is the run's tick
                           (default: the training tick, 65 Hz in the paper)
``campaign_id``,   string  optional: rows of one (campaign_id, run_id) are one history;
``run_id``                 without them the whole frame is one history
=================  ======  ============================================================

Rows of a history in time order. **Output**: a DataFrame with the six wrench channels
``fx_n fy_n fz_n`` (N) and ``tx_nm ty_nm tz_nm`` (N m), one row per input row (same index):
exactly :meth:`LearnedLegModel.wrench` of each history, including its first ``seq_len - 1``
start-up ticks (the history is padded by repeating its first tick).
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import mlflow.pyfunc  # this module is imported only to log or load an MLflow model
import pandas as pd

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.errors import ModelError
from workbench.learn.config import FEATURES

#: the key of the model folder among the MLflow model's artifacts
ARTIFACT_KEY = "leg_model"
#: optional input columns
OPTIONAL_COLUMNS = ("time_s", "campaign_id", "run_id")


class LearnedLegPyfunc(mlflow.pyfunc.PythonModel):
    """``predict(frame) -> wrench frame`` for the model folder logged as the artifact ``leg_model``."""

    def load_context(self, context) -> None:
        """Load the model folder (``workbench.learn.legmodel.load_model``)."""
        from workbench.learn.legmodel import load_model

        self.model = load_model(context.artifacts[ARTIFACT_KEY])

    def predict(self, context, model_input: pd.DataFrame, params: dict[str, Any] | None = None) -> pd.DataFrame:
        """The wrench of every row (see the module docstring)."""
        return predict_frame(self.model, model_input)


def predict_frame(model, frame):
    """The model's wrench for every row of an input frame (module docstring), as a DataFrame."""
    import numpy as np

    from workbench.hydro.motion import LegMotion

    if not isinstance(frame, pd.DataFrame):
        frame = pd.DataFrame(frame)
    missing = [c for c in FEATURES if c not in frame.columns]
    if missing:
        raise ModelError(f"the input frame lacks the column(s) {', '.join(missing)}",
                         hint=f"needs {', '.join(FEATURES)} (optional: {', '.join(OPTIONAL_COLUMNS)})")
    keys = [c for c in ("campaign_id", "run_id") if c in frame.columns]
    if keys:
        groups = list(frame.groupby(keys, sort=False, dropna=False).indices.values())
    else:
        groups = [np.arange(len(frame))]
    out = np.zeros((len(frame), len(WRENCH_CHANNELS)))
    for idx in groups:
        part = frame.iloc[idx]
        dt = model.dt_s
        if "time_s" in part.columns and len(part) > 1:
            steps = np.diff(part["time_s"].to_numpy(dtype=float))
            steps = steps[np.isfinite(steps) & (steps > 0)]
            if len(steps):
                dt = float(np.median(steps))
        col = {c: part[c].to_numpy(dtype=float) for c in FEATURES}
        motion = LegMotion.from_arrays(dt, col["theta_h_deg"], col["theta_k_deg"], col["omega_h_dps"],
                                       col["omega_k_dps"], col["flow_speed_mps"])
        out[idx] = model.wrench(motion)[0]
    return pd.DataFrame(out, columns=list(WRENCH_CHANNELS), index=frame.index)


def signature():
    """Inputs: the five features (required), ``time_s``, ``campaign_id``, ``run_id`` (optional); outputs: 6 channels."""
    from mlflow.models import ModelSignature
    from mlflow.types import ColSpec, Schema

    inputs = [ColSpec("double", c) for c in FEATURES]
    inputs += [ColSpec("double", "time_s", required=False), ColSpec("string", "campaign_id", required=False),
               ColSpec("string", "run_id", required=False)]
    return ModelSignature(inputs=Schema(inputs), outputs=Schema([ColSpec("double", c) for c in WRENCH_CHANNELS]))


def input_example(table, ticks: int = 40):
    """The first ``ticks`` ticks of the first run of a :class:`~workbench.learn.windows.RunTable` as an input frame."""
    import numpy as np

    if table is None or table.n_runs == 0:
        return None
    sl = table.run_slice(0)
    x = table.x[sl][:ticks].astype(np.float64)
    dt = float(table.runs["dt_s"][0])
    frame = {c: x[:, i] for i, c in enumerate(FEATURES)}
    frame["time_s"] = np.round(np.arange(len(x)) * dt, 6)
    frame["campaign_id"] = str(table.runs["campaign_id"][0])
    frame["run_id"] = str(table.runs["run_id"][0])
    return pd.DataFrame(frame)


def requirements() -> list[str]:
    """Pinned versions of what loading needs besides the workbench itself (MLflow's inference would import torch)."""
    from importlib.metadata import PackageNotFoundError, version

    out = []
    for dist in ("mlflow", "torch", "numpy", "pandas", "polars", "scipy"):
        try:
            out.append(f"{dist}=={version(dist)}")
        except PackageNotFoundError:
            pass
    return out


def log_leg_model(folder: str | Path, *, table=None, name: str = "model", tags: dict[str, str] | None = None):
    """Log a model folder as an MLflow pyfunc model of the active run; returns MLflow's ``ModelInfo``."""
    entry = Path(__file__).with_name("mlflow_entry.py")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # MLflow's notes on pip/uv environments and integer columns
        return mlflow.pyfunc.log_model(
            name=name, python_model=str(entry), artifacts={ARTIFACT_KEY: str(folder)}, signature=signature(),
            input_example=input_example(table), pip_requirements=requirements(),
            metadata={"workbench_schema": "workbench/learned-leg-model@1",
                      "loads_with": "mlflow.pyfunc.load_model or workbench.hydro.legmodel.load_leg_model"},
            tags=dict(tags or {}))

