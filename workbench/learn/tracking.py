"""MLflow bookkeeping for learned leg models: run tags, model artifacts, the registry and its alias.

Layout (see docs/learning.md): experiment ``fed-lstm`` holds one run per ``workbench train``,
one parent run per ``workbench tune`` with a child run per trial, and one run per
``workbench evaluate``. Every run is tagged ``campaign``, ``variant``, ``git_commit``,
``dvc_stage`` and ``kind`` (train | trial | tune | evaluate). A trained model is logged as the
artifact folder ``model/`` (``model.json`` + ``weights.pt``: the state dict, the architecture
and the normalisation; no pickled code) and registered as a version of ``fed-lstm``; the alias
``champion`` names the version the rest of the pipeline loads (``models:/fed-lstm@champion``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

from workbench.errors import ModelError

MODEL_ARTIFACT = "model"


def dvc_stage_name(explicit: str | None = None) -> str:
    """The DVC stage a run belongs to: explicit, else ``DVC_STAGE`` (set by ``dvc repro``), else ``manual``."""
    return explicit or os.environ.get("DVC_STAGE") or "manual"


def run_tags(*, kind: str, campaigns: list[str] | tuple[str, ...], variant: str | None = None,
             dvc_stage: str | None = None, **extra: Any) -> dict[str, str]:
    """The tags every learn run carries, so runs compare side by side in the MLflow UI."""
    from workbench.project import git_commit

    tags = {"kind": kind, "campaign": "+".join(campaigns) or "unknown", "git_commit": git_commit(),
            "dvc_stage": dvc_stage_name(dvc_stage)}
    if variant:
        tags["variant"] = variant
    if os.environ.get("DVC_EXP_NAME"):
        tags["dvc_exp"] = os.environ["DVC_EXP_NAME"]
    tags.update({k: str(v) for k, v in extra.items() if v is not None})
    return tags


def flat_params(d: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Nested config -> ``{"model.hidden_size": "64", ...}`` (MLflow params are strings)."""
    out: dict[str, str] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(flat_params(v, key + "."))
        else:
            out[key] = str(v)[:500]
    return out


def flat_metrics(d: Mapping[str, Any], prefix: str = "", sep: str = "_") -> dict[str, float]:
    """Nested numeric dict -> flat MLflow metric names (non-numbers and NaN dropped)."""
    out: dict[str, float] = {}
    for k, v in d.items():
        key = f"{prefix}{sep}{k}" if prefix else str(k)
        if isinstance(v, Mapping):
            out.update(flat_metrics(v, key, sep))
        elif isinstance(v, (int, float)) and not isinstance(v, bool) and v == v:
            out[key] = float(v)
    return out


def setup(tracking_uri: str | None, experiment: str | None) -> str:
    """Point MLflow at the store (project default, env or explicit), quieten its INFO lines; returns the URI."""
    import logging

    from workbench.project import setup_mlflow

    logging.getLogger("mlflow").setLevel(logging.WARNING)
    return setup_mlflow(tracking_uri, experiment)


def register_model(run, name: str, alias: str | None, tags: Mapping[str, str] | None = None) -> str:
    """Register the run's ``model/`` artifact as a new version of ``name`` and point ``alias`` at it."""
    from mlflow import MlflowClient

    client = MlflowClient()
    try:
        client.get_registered_model(name)
    except Exception:  # noqa: BLE001 - not there yet (another process may race us: tolerate "exists")
        try:
            client.create_registered_model(name, description="Learned leg force models (FED-LSTM and variants); "
                                                              "load with workbench.hydro.legmodel.load_leg_model")
        except Exception:  # noqa: BLE001
            pass
    mv = client.create_model_version(name, source=f"{run.info.artifact_uri}/{MODEL_ARTIFACT}", run_id=run.info.run_id,
                                     tags=dict(tags or {}))
    if alias:
        client.set_registered_model_alias(name, alias, mv.version)
    return str(mv.version)


def model_uri(name: str, alias: str = "champion") -> str:
    """``models:/<name>@<alias>``."""
    return f"models:/{name}@{alias}"


def download_model(uri: str, tracking_uri: str | None = None) -> tuple[Path, dict]:
    """Resolve a ``models:/name@alias`` (or ``models:/name/version``) URI to a local folder and its version info."""
    import mlflow
    from mlflow import MlflowClient

    from workbench.project import mlflow_tracking_uri

    mlflow.set_tracking_uri(mlflow_tracking_uri(tracking_uri))
    body = uri[len("models:/"):]
    client = MlflowClient()
    try:
        if "@" in body:
            name, alias = body.split("@", 1)
            mv = client.get_model_version_by_alias(name, alias)
        else:
            name, version = body.rsplit("/", 1)
            mv = client.get_model_version(name, version)
        path = mlflow.artifacts.download_artifacts(artifact_uri=mv.source)
    except Exception as exc:  # noqa: BLE001 - MLflow raises many kinds; one line for the user
        raise ModelError(f"cannot load {uri} from {mlflow.get_tracking_uri()} ({type(exc).__name__}: "
                         f"{str(exc).splitlines()[0][:160] if str(exc) else ''})",
                         hint="train first (workbench train) or pass --tracking-uri") from exc
    return Path(path), {"model_uri": uri, "model_version": str(mv.version), "run_id": mv.run_id}
