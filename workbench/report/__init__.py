"""The final report: campaign quality, drag fit, EF-vs-LSTM accuracy, gaits, trial scores, diagnosis.

:func:`collect` reads the pipeline's result files (the data contract's section 5 and each
stage's own summaries) into plain dicts; :func:`render_markdown` and :func:`render_html` turn
them into a page whose figures are the stages' own PNGs (linked relative to the report, so the
report folder stays small) with links to the MLflow runs behind each step.

The sections live in one module each, by what they report: ``data`` (campaigns, drag, leg models,
sequence length), ``gaits`` (optimised gaits, sensitivity), ``pool`` and ``verdict`` (open-water
trials), ``diagnosis``, ``runs`` (MLflow links); ``headline`` writes headline.json, ``page`` holds
the section type and the renderings, and ``read`` every read of the datasets' outputs.
"""

from __future__ import annotations

from pathlib import Path

from workbench.report.data import (
    campaigns_section,
    drag_section,
    leg_models_section,
    seq_len_inputs,
    seq_len_section,
)
from workbench.report.diagnosis import diagnosis_section, trajectory_section
from workbench.report.gaits import OBJECTIVES, gaits_section, sensitivity_section
from workbench.report.headline import headline
from workbench.report.page import (
    FIGURE_CAPTIONS,
    MODEL_LABELS,
    Section,
    caption,
    render_html,
    render_markdown,
)
from workbench.report.pool import SCORE_NAMES, trials_section, turn_spaces
from workbench.report.runs import MLFLOW_EXPERIMENTS, mlflow_section
from workbench.report.verdict import TRIAL_PROTOCOL, pool_verdict

__all__ = [
    "FIGURE_CAPTIONS", "MLFLOW_EXPERIMENTS", "MODEL_LABELS", "OBJECTIVES", "SCORE_NAMES", "TRIAL_PROTOCOL", "Section",
    "campaigns_section", "caption", "collect", "diagnosis_section", "drag_section", "gaits_section", "headline",
    "leg_models_section", "mlflow_section", "pool_verdict", "render_html", "render_markdown", "seq_len_inputs",
    "seq_len_section", "sensitivity_section", "trajectory_section", "trials_section", "turn_spaces",
]


def collect(datasets: Path, tracking_uri: str | None = None, ui_url: str = "http://127.0.0.1:5000",
            with_mlflow: bool = True) -> list[Section]:
    """All report sections, in the order the data flows through the workbench."""
    secs = [campaigns_section(datasets), drag_section(datasets), leg_models_section(datasets),
            gaits_section(datasets), sensitivity_section(datasets), trials_section(datasets), seq_len_section(datasets),
            diagnosis_section(datasets), trajectory_section(datasets)]
    if with_mlflow:
        secs.append(mlflow_section(tracking_uri, ui_url))
    return secs
