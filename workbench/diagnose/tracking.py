"""MLflow record of a diagnosis: one run in experiment ``diagnose`` per ``workbench diagnose`` (tunnel or trajectory level).

Params: the diagnosed model, the campaign, the settings (flattened). Metrics: held-out MSE per
channel before and after, the share removed, the number of effects, and each effect's canonical
parameters and held-out reduction (``effect.<name>.<param>``). Tags: the claimed effects, the
unexplained kinds, ``git_commit`` and ``dvc_stage``. Artifacts: the whole output folder
(diagnosis.json, augmented_model.json, report.md, figures/) and ``params.json``.

Logged through :mod:`workbench.tracking`: run names ``diagnose <model> <campaign> @<commit>``
(``dvc:<stage> ...`` from a DVC stage), the common tags, every parameter (no cut at 100).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

EXPERIMENT = "diagnose"


def log_diagnosis(d, out_dir: str | Path, tracking_uri: str | None = None) -> str:
    """Log ``d`` and the files in ``out_dir``; returns the MLflow run id."""
    from workbench.tracking import log_artifacts, log_metrics, run_name, run_tags, tracked_run

    tags = run_tags(kind="diagnose", campaigns=[d.campaign_id], model=d.model,
                    effects=",".join(e.name for e in d.effects) or "none",
                    unexplained=",".join(u.kind for u in d.unexplained) or "none")
    params = {"model": d.model, "campaign": d.campaign_id, "heldout_runs": len(d.heldout_runs),
              "train_runs": len(d.train_runs), "settings": dataclasses.asdict(d.settings)}
    metrics: dict[str, float] = {"n_effects": float(len(d.effects)), "runtime_s": float(d.runtime_s)}
    for c, v in d.mse_before.items():
        metrics[f"mse_before.{c}"] = v
        metrics[f"mse_after.{c}"] = d.mse_after[c]
        if v > 0:
            metrics[f"removed.{c}"] = 1.0 - d.mse_after[c] / v
    for e in d.effects:
        metrics[f"effect.{e.name}.heldout_mse_reduction"] = e.heldout_mse_reduction
        for k, v in e.params.items():
            if isinstance(v, float):
                metrics[f"effect.{e.name}.{k}"] = v
    with tracked_run(name=run_name("diagnose", d.model, [d.campaign_id]), tags=tags, experiment=EXPERIMENT,
                     tracking_uri_=tracking_uri, params=params) as run:
        log_metrics(metrics)
        log_artifacts(folders={"": out_dir})
        return run.info.run_id


def log_trajectory_diagnosis(doc: dict, diagnoses: dict, out_dir: str | Path, settings=None,
                             tracking_uri: str | None = None) -> str:
    """Log a trajectory-level diagnosis (``diagnose --trials``) like the tunnel level; returns the run id.

    One run in experiment ``diagnose``. Tags: ``kind`` = ``diagnose-trajectory``, the trials folder,
    the models, the claimed effects and unexplained kinds, ``git_commit``, ``dvc_stage``. Params:
    each model's spec, the reference session, the settings (flattened). Metrics per model label:
    ``rms_position_m.<label>``, ``rms_heading_deg.<label>``, ``mean_final_position_m.<label>``,
    ``n_trials.<label>``, and each effect's parameters (``effect.<label>.<name>.<param>``).
    Artifacts: the output folder (trajectory_errors.json/.png, trajectory_diagnosis.json).
    """
    from workbench.tracking import log_artifacts, log_metrics, run_name, run_tags, tracked_run

    trials = Path(str(doc.get("trials", "trials"))).name
    models = doc.get("models") or {}
    effects = sorted({f"{lab}:{e['name']}" for lab, d in diagnoses.items() for e in d.effects})
    unexplained = sorted({f"{lab}:{u['kind']}" for lab, d in diagnoses.items() for u in d.unexplained})
    tags = run_tags(kind="diagnose-trajectory", campaigns=[trials], trials=str(doc.get("trials")),
                    model=",".join(models) or "none", effects=",".join(effects) or "none",
                    unexplained=",".join(unexplained) or "none")
    params = _trajectory_params(doc, models, settings)
    metrics = _trajectory_metrics(doc, models, diagnoses)
    with tracked_run(name=run_name("diagnose-trajectory", ",".join(models) or None, [trials]), tags=tags,
                     experiment=EXPERIMENT, tracking_uri_=tracking_uri, params=params) as run:
        log_metrics(metrics)
        log_artifacts(folders={"": out_dir})
        return run.info.run_id


def _trajectory_params(doc: dict, models: dict, settings) -> dict:
    """The trajectory run's params: trials, gaits, reference, wall margin, each model's spec and the settings."""
    params: dict = {"trials": str(doc.get("trials")), "gaits": str(doc.get("gaits")),
                    "reference": str(doc.get("reference")), "wall_margin_m": str(doc.get("wall_margin_m")),
                    "model": {lab: str(m.get("spec")) for lab, m in models.items()}}
    if settings is not None and dataclasses.is_dataclass(settings):
        params["settings"] = dataclasses.asdict(settings)
    return params


def _trajectory_metrics(doc: dict, models: dict, diagnoses: dict) -> dict[str, float]:
    """The trajectory run's metrics: runtime, each model's errors, each diagnosis's errors and effect parameters."""
    metrics: dict[str, float] = {"runtime_s": float(doc.get("runtime_s") or 0.0)}
    for lab, m in models.items():
        for key in ("rms_position_m", "rms_heading_deg", "mean_final_position_m", "n_trials", "sim_seconds"):
            if isinstance(m.get(key), (int, float)):
                metrics[f"{key}.{lab}"] = float(m[key])
    for lab, d in diagnoses.items():
        metrics.update(_diagnosis_metrics(lab, d))
    return metrics


def _diagnosis_metrics(lab: str, d) -> dict[str, float]:
    """One trajectory diagnosis's RMS errors before and after, and its effects' parameters, under label ``lab``."""
    metrics: dict[str, float] = {}
    j = d.to_json()
    for key in ("rms_position_error_m", "rms_heading_error_deg"):
        for when in ("before", "after"):
            v = (j.get(key) or {}).get(when)
            if isinstance(v, float):
                metrics[f"{key}.{when}.{lab}"] = v
    for e in d.effects:
        for k, v in e["params"].items():
            if isinstance(v, float):
                metrics[f"effect.{lab}.{e['name']}.{k}"] = v
    return metrics
