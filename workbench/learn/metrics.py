"""Leg force models scored on held-out runs: MSE and R^2 per channel, per flow speed, per parameter set.

Every model is run through the same :class:`LegForceModel` interface on whole runs and scored on
the same ticks: a run's first ``skip`` ticks (those before a full LSTM window) are left out for
every model. R^2 is pooled over all scored ticks of the split (1 - SSE / sum of squares about
the pooled mean), per channel. The result per model is the contract's section-5 record
(``mse``, ``r2``, ``mse_by_flow_speed`` keyed ``"0.10"``) plus extra keys: ``r2_by_flow_speed``,
``by_parameter_set`` (pooled over a set's runs), ``by_run`` (one MSE per run, the box plot's
data), ``n_runs`` and ``n_ticks``.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.hydro.legmodel import LegForceModel
from workbench.learn.windows import RunTable, motion_of_run, set_label


def speed_key(v: float) -> str:
    """Flow-speed key of the metrics file: two decimals (``"0.10"``)."""
    return f"{v:.2f}"


class _Acc:
    """Pooled squared errors and target moments per channel."""

    def __init__(self):
        self.sse = np.zeros(6)
        self.sy = np.zeros(6)
        self.syy = np.zeros(6)
        self.n = 0

    def add(self, err: np.ndarray, y: np.ndarray) -> None:
        self.sse += (err * err).sum(0)
        self.sy += y.sum(0)
        self.syy += (y * y).sum(0)
        self.n += len(y)

    def mse(self) -> dict[str, float]:
        return {c: float(v) for c, v in zip(WRENCH_CHANNELS, self.sse / max(self.n, 1), strict=False)}

    def r2(self) -> dict[str, float]:
        sst = self.syy - self.sy**2 / max(self.n, 1)
        return {c: (float(1 - e / s) if s > 0 else float("nan")) for c, e, s in zip(WRENCH_CHANNELS, self.sse, sst, strict=False)}


def predict_runs(table: RunTable, runs, model: LegForceModel) -> list[np.ndarray]:
    """The model's (T, 6) prediction for each run (one call per run, whole run as input)."""
    return [np.asarray(model.wrench(motion_of_run(table, int(r)))[0], dtype=np.float64) for r in runs]


def score_runs(table: RunTable, runs, models: Mapping[str, LegForceModel], skip: int = 15,
               predictions: Mapping[str, list[np.ndarray]] | None = None) -> dict:
    """Score each model on the given runs (indices into ``table``); see the module docstring."""
    runs = [int(r) for r in runs]
    meta = table.runs
    out: dict[str, dict] = {}
    for name, model in models.items():
        preds = predictions[name] if predictions and name in predictions else predict_runs(table, runs, model)
        total, by_speed, by_set = _Acc(), {}, {}
        labels, per_run = {}, []
        for r, pred in zip(runs, preds, strict=False):
            sl = table.run_slice(r)
            y = table.y[sl].astype(np.float64)[skip:]
            err = pred[skip:] - y
            if len(y) == 0:
                continue
            sk = speed_key(float(meta["flow_speed_mps"][r]))
            key = tuple(meta["set_key"][r])
            params = {c: float(meta[c][r]) for c in table.param_columns}
            labels[key] = (set_label(params), params)
            total.add(err, y)
            by_speed.setdefault(sk, _Acc()).add(err, y)
            by_set.setdefault(key, {}).setdefault(sk, _Acc()).add(err, y)
            per_run.append({"run": f"{meta['campaign_id'][r]}/{meta['run_id'][r]}", "set": labels[key][0],
                            "flow_speed_mps": float(meta["flow_speed_mps"][r]),
                            "mse": {c: float(v) for c, v in zip(WRENCH_CHANNELS, (err * err).mean(0), strict=False)}})
        sets = []
        for key, speeds in sorted(by_set.items()):
            pooled = _Acc()
            for acc in speeds.values():
                pooled.sse += acc.sse
                pooled.sy += acc.sy
                pooled.syy += acc.syy
                pooled.n += acc.n
            sets.append({"set": labels[key][0], "params": labels[key][1], "mse": pooled.mse(), "r2": pooled.r2(),
                         "mse_by_flow_speed": {s: a.mse() for s, a in sorted(speeds.items())}})
        out[name] = {
            "mse": total.mse(), "r2": total.r2(),
            "mse_by_flow_speed": {s: a.mse() for s, a in sorted(by_speed.items())},
            "r2_by_flow_speed": {s: a.r2() for s, a in sorted(by_speed.items())},
            "by_parameter_set": sets, "by_run": per_run,
            "n_runs": len(per_run), "n_ticks": int(total.n), "skipped_ticks_per_run": int(skip),
            "model": model.describe(),
        }
    return out


def mse_ratios(metrics: Mapping[str, dict], num: str = "lstm", den: str = "ef",
               channels=("fy_n", "fz_n", "tx_nm")) -> dict[str, dict[str, float]]:
    """MSE(num) / MSE(den) per flow speed and channel (the "Done when" check: at most 0.5)."""
    a, b = metrics[num]["mse_by_flow_speed"], metrics[den]["mse_by_flow_speed"]
    return {s: {c: a[s][c] / b[s][c] if b[s][c] > 0 else float("inf") for c in channels} for s in a if s in b}
