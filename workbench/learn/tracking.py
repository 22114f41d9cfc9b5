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
    """Register the run's ``model/`` artifact as a version of ``name`` and point ``alias`` at it.

    Safe when several machines do it at once on one shared store (tune workers finishing
    together): a run keeps one version (the oldest, when two machines registered it at the same
    moment), and a registry write that loses a race on the store's unique keys is retried.
    """
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
    run_id = run.info.run_id
    mv = version_of_run(client, name, run_id)
    if mv is None:
        mine = retry_race(lambda: client.create_model_version(
            name, source=f"{run.info.artifact_uri}/{MODEL_ARTIFACT}", run_id=run_id, tags=dict(tags or {})))
        # another machine may have registered the same run a moment before: keep its (older) version
        mv = version_of_run(client, name, run_id) or mine
        if mv.version != mine.version:
            client.delete_model_version(name, mine.version)
    if alias:
        retry_race(lambda: client.set_registered_model_alias(name, alias, mv.version))
    return str(mv.version)


def version_of_run(client, name: str, run_id: str):
    """The oldest version of registered model ``name`` made from run ``run_id``, or None."""
    found = client.search_model_versions(f"name = '{name}' and run_id = '{run_id}'")
    return min(found, key=lambda v: int(v.version)) if found else None


def retry_race(call, errors: tuple[type[BaseException], ...] | None = None, attempts: int = 6):
    """``call()``, retried with a random back-off when a shared store refuses it because a concurrent writer won.

    MLflow's SQL registry sets an alias by select-then-insert, so two writers of one alias can
    both insert and one fails on the primary key; Optuna's first schema creation on an empty
    database races the same way. On the retry the winner's row or table exists. ``errors``
    defaults to MLflow's exceptions.
    """
    import random
    import time

    if errors is None:
        from mlflow.exceptions import MlflowException

        errors = (MlflowException,)
    for attempt in range(attempts):
        try:
            return call()
        except errors:
            if attempt == attempts - 1:
                raise
            time.sleep(0.2 + random.random() * (0.5 + attempt))
    raise AssertionError("unreachable")


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
