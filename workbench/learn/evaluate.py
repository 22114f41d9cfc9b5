"""EF vs learned models on the held-out test parameter sets: metrics and the paper's figures.

Only measured runs of the split's test sets are scored (interpolated rows never enter a metric).
Every model sees whole runs through the leg force model interface and is scored on the same
ticks: each run's first ``skip`` ticks, those before the longest model window is full, are left
out for all models alike.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from workbench.errors import DataError
from workbench.hydro.legmodel import LegForceModel
from workbench.learn.metrics import predict_runs, score_runs
from workbench.learn.split import ParameterSplit, _matches
from workbench.learn.windows import RunTable, motion_of_run, set_label


def common_skip(models: Mapping[str, LegForceModel]) -> int:
    """Ticks to leave out at each run start: the longest model window minus one."""
    return max([int(getattr(m, "seq_len", 1)) - 1 for m in models.values()] + [0])


def evaluate_models(table: RunTable, split: ParameterSplit, models: Mapping[str, LegForceModel],
                    skip: int | None = None) -> tuple[dict, dict]:
    """Metrics (contract section 5 plus extra keys) and the predictions per model on the test runs."""
    runs = split.runs(table, "test", measured_only=True)
    if len(runs) == 0:
        raise DataError("no measured runs of the split's test parameter sets in the data",
                        hint="evaluate on the campaign the model was trained on (the split names its sets)")
    skip = common_skip(models) if skip is None else skip
    preds = {name: predict_runs(table, runs, m) for name, m in models.items()}
    return score_runs(table, runs, models, skip, preds), {"runs": runs, "predictions": preds, "skip": skip}


def pick_figure_run(table: RunTable, runs: Sequence[int], spec: Mapping[str, float],
                    flow_speed_mps: float | None) -> tuple[int, str | None]:
    """The test run for a figure: a set matching ``spec`` at the flow speed closest to the one asked.

    When no held-out set matches, the nearest one (in the spec's parameters) is used and the
    returned note says so (it goes on the figure).
    """
    meta = table.runs
    runs = [int(r) for r in runs]
    params = [{c: float(meta[c][r]) for c in table.param_columns} for r in runs]
    speed = meta["flow_speed_mps"].to_numpy()
    match = [i for i, p in enumerate(params) if _matches(p, spec)]
    note = None
    if not match:
        dist = [sum((p[k] - float(v)) ** 2 for k, v in spec.items()) for p in params]
        best = min(dist)
        match = [i for i, d in enumerate(dist) if d == best]
        want = ", ".join(f"{k}={v:g}" for k, v in spec.items())
        note = f"no held-out set with {want}; nearest held-out set shown"
    target = float(np.median(speed[list(runs)])) if flow_speed_mps is None else flow_speed_mps
    i = min(match, key=lambda i: (abs(speed[runs[i]] - target), i))
    return int(runs[i]), note


def prediction_figures(table: RunTable, result: dict, metrics: dict, specs: Sequence[Mapping[str, float]],
                       flow_speed_mps: float | None = None, cycles: float = 2.0) -> list:
    """One Fig. 4-style figure per spec (measured vs every model), over the run's last ``cycles`` cycles."""
    from workbench.learn.figures import prediction_figure

    runs = [int(r) for r in result["runs"]]
    figs = []
    for spec in specs:
        r, note = pick_figure_run(table, runs, spec, flow_speed_mps)
        i = runs.index(r)
        meta = table.runs
        sl = table.run_slice(r)
        t = np.arange(table.length[r]) * float(meta["dt_s"][r])
        f = float(meta["frequency_hz"][r]) if "frequency_hz" in meta.columns else 0.0
        first = result["skip"]
        if f > 0:
            first = max(first, int(len(t) - cycles / f / float(meta["dt_s"][r])))
        run_mse = {name: next(x["mse"] for x in metrics[name]["by_run"]
                              if x["run"] == f"{meta['campaign_id'][r]}/{meta['run_id'][r]}") for name in metrics}
        params = {c: float(meta[c][r]) for c in table.param_columns}
        title = (f"{meta['campaign_id'][r]}/{meta['run_id'][r]}: {set_label(params)}, "
                 f"flow {float(meta['flow_speed_mps'][r]):.2f} m/s (held-out test set; per-run MSE in titles)")
        figs.append(prediction_figure(title, t, motion_of_run(table, r), table.y[sl].astype(np.float64),
                                      {n: p[i] for n, p in result["predictions"].items()}, first=first,
                                      mse=run_mse, note=note))
    return figs
