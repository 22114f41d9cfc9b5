"""Compatibility: the MLflow helpers moved to :mod:`workbench.tracking` (one module for every package).

Kept so that ``from workbench.learn.tracking import register_model`` (and the other names below)
keeps working; new code imports :mod:`workbench.tracking`.
"""

from __future__ import annotations

from workbench.tracking import (  # noqa: F401 - re-exported
    MODEL_ARTIFACT,
    download_model,
    dvc_stage_name,
    flat_metrics,
    model_uri,
    register_model,
    retry_race,
    run_tags,
    setup,
    version_of_run,
)
