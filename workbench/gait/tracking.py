"""MLflow record of an optimisation: one run per task and model in the experiment ``optimize``.

Logged through :mod:`workbench.tracking` (run name ``optimize <task> <model> <campaigns> @<commit>``,
``dvc:<stage> ...`` from a DVC stage; the common tags; ``state``). Params: the flattened settings,
all of them (``params.json`` holds the document); metrics with steps: ``hypervolume``, ``best_score``,
``evaluations`` and ``unconverged`` (the population's unconverged simulations) per generation;
``final_unconverged_gaits`` counts every unconverged simulation of the run; final metrics from the outcome; artifacts: the gait file, the
controller file, the best-8 table (CSV, and as an MLflow table), the history and the plots.
Tags: ``kind`` (optimize), ``campaign`` (the campaigns behind the leg model and the body drag),
``task``, ``model``, ``model_spec``, ``git_commit``, ``dvc_stage``, and where the leg model came
from: ``model_uri``, ``model_version`` and ``model_run_id`` (a registry spec, resolved: the version
actually used) or ``model_path`` (a saved folder), those known.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from workbench.gait.optimize import GaitOutcome


def log_outcome(outcome: GaitOutcome, settings: Mapping[str, Any], folder: Path, files: list[Path], *,
                model_spec: str, tracking_uri: str | None, experiment: str, dvc_stage: str | None = None,
                campaigns: list[str] | tuple[str, ...] = (), model_source: Mapping[str, str] | None = None) -> str:
    """Log one optimisation as an MLflow run (:mod:`workbench.tracking`); returns the run id."""
    import mlflow

    from workbench.tracking import (
        log_artifacts,
        log_metric_series,
        log_metrics,
        run_name,
        run_tags,
        tracked_run,
    )

    source = {tag: str((model_source or {})[key]) for key, tag in (
        ("model_uri", "model_uri"), ("model_version", "model_version"), ("run_id", "model_run_id"),
        ("model_path", "model_path")) if (model_source or {}).get(key)}
    tags = run_tags(kind="optimize", campaigns=campaigns, dvc_stage=dvc_stage, task=outcome.task, model=outcome.model,
                    model_spec=model_spec, **source)
    name = run_name("optimize", f"{outcome.task} {outcome.model}", campaigns, dvc_stage)
    with tracked_run(name=name, tags=tags, experiment=experiment, tracking_uri_=tracking_uri, params=settings) as run:
        history = outcome.result.history
        log_metric_series({"hypervolume": [(g.gen, g.hypervolume) for g in history],
                           "best_score": [(g.gen, g.best_score) for g in history],
                           "evaluations": [(g.gen, float(g.evaluations)) for g in history],
                           "unconverged": [(g.gen, float(g.unconverged)) for g in history]})
        final = {k: v for k, v in outcome.metrics.items() if k not in ("hypervolume", "tabulation")}
        final.update({f"tabulation_{k}": v for k, v in (outcome.metrics.get("tabulation") or {}).items()})
        log_metrics({f"final_{k}": v for k, v in final.items()}, step=0)
        mlflow.log_table({k: [row[k] for row in outcome.table] for k in outcome.table[0]}, "best_table.json")
        log_artifacts(files, folders={folder.name: folder})
        return run.info.run_id
