"""MLflow record of an optimisation: one run per task and model in the experiment ``optimize``.

Params: the flattened settings; metrics with steps: ``hypervolume``, ``best_score``,
``evaluations`` and ``unconverged`` (the population's unconverged simulations) per generation;
``final_unconverged_gaits`` counts every unconverged simulation of the run; final metrics from the outcome; artifacts: the gait file, the
controller file, the best-8 table (CSV, and as an MLflow table), the history and the plots.
Tags: ``kind`` (optimize), ``campaign`` (the campaigns behind the leg model and the body drag),
``task``, ``model``, ``model_spec``, ``git_commit``, ``dvc_stage``, and where the leg model came
from: ``model_uri``, ``model_version`` and ``model_run_id`` (a registry spec, resolved: the version
actually used) or ``model_path`` (a saved folder), those known.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any, Mapping

from workbench.gait.optimize import GaitOutcome


def _flat(d: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    out: dict[str, str] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(_flat(v, key + "."))
        else:
            out[key] = str(v)[:500]
    return out


def log_outcome(outcome: GaitOutcome, settings: Mapping[str, Any], folder: Path, files: list[Path], *,
                model_spec: str, tracking_uri: str | None, experiment: str, dvc_stage: str | None = None,
                campaigns: list[str] | tuple[str, ...] = (), model_source: Mapping[str, str] | None = None) -> str:
    """Log one optimisation as an MLflow run; returns the run id."""
    import mlflow
    from mlflow.entities import Metric, Param

    from workbench.project import git_commit, setup_mlflow

    setup_mlflow(tracking_uri, experiment)
    tags = {"kind": "optimize", "campaign": "+".join(dict.fromkeys(campaigns)) or "unknown",
            "task": outcome.task, "model": outcome.model, "model_spec": model_spec, "git_commit": git_commit(),
            "dvc_stage": dvc_stage or os.environ.get("DVC_STAGE") or "manual"}
    for key, tag in (("model_uri", "model_uri"), ("model_version", "model_version"), ("run_id", "model_run_id"),
                     ("model_path", "model_path")):
        if (model_source or {}).get(key):
            tags[tag] = str(model_source[key])
    with mlflow.start_run(run_name=f"{outcome.task}-{outcome.model}", tags=tags) as run:
        client = mlflow.MlflowClient()
        now = int(time.time() * 1000)
        params = [Param(k, v) for k, v in _flat(settings).items()]
        metrics = []
        for g in outcome.result.history:
            metrics += [Metric("hypervolume", g.hypervolume, now, g.gen), Metric("best_score", g.best_score, now, g.gen),
                        Metric("evaluations", float(g.evaluations), now, g.gen),
                        Metric("unconverged", float(g.unconverged), now, g.gen)]
        final = {k: float(v) for k, v in outcome.metrics.items()
                 if isinstance(v, (int, float)) and not isinstance(v, bool) and k != "hypervolume"}
        final.update({f"tabulation_{k}": float(v) for k, v in outcome.metrics.get("tabulation", {}).items()
                      if isinstance(v, (int, float))})
        metrics += [Metric(f"final_{k}", v, now, 0) for k, v in final.items() if v == v]
        for i in range(0, len(params), 100):
            client.log_batch(run.info.run_id, params=params[i:i + 100])
        for i in range(0, len(metrics), 1000):
            client.log_batch(run.info.run_id, metrics=metrics[i:i + 1000])
        mlflow.log_table({k: [row[k] for row in outcome.table] for k in outcome.table[0]}, "best_table.json")
        for f in files:
            mlflow.log_artifact(str(f))
        mlflow.log_artifacts(str(folder), artifact_path=folder.name)
        return run.info.run_id
