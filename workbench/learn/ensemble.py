"""A deep ensemble of the FED-LSTM: K members trained through ``train(cfg)`` with different seeds.

The members share the data and the split (``data.split.seed`` is not touched) and differ in their
initialisation and window draws (``trainer.seed``). The ensemble predicts the mean of the members
and, per channel, a 90 % interval of a *reading*::

    mean  = mean_k f_k(x)
    var   = scale_c^2 * (var_k f_k(x) + noise_c)

``noise_c`` is the channel's residual noise (what the members' mean misses on the validation split
beyond the members' own spread), and ``scale_c`` a per-channel calibration factor fitted on the
validation split only, by a rule fixed in advance (nothing is chosen by looking at the test split):
the scale is the pooled quantile of the validation scores ``|y - mean| / sqrt(var + noise)`` at the
smallest level whose *leave-one-run-out* coverage on validation is at least 90 % (cross-conformal by
run, :func:`calibrate`). A model's error is mostly a misfit of whole parameter sets, so readings of
one run are not exchangeable and a plain pooled 90 % quantile is optimistic for new parameter sets;
holding out whole runs measures that on the validation split itself. The coverage on the test split,
before (scale 1) and after calibration, is what ``ensemble.json`` reports (with two other val-fitted
rules for comparison, never used to choose).

The folder (:func:`train_ensemble` returns its files as bytes; ``workbench train-ensemble`` writes
them through ``workbench/atomic.py`` as one set; :func:`load_ensemble` reads it back through
:mod:`workbench.learn.legmodel`, learn's edge for saved models)::

    ENSEMBLE_DIR/ensemble.json        schema, members, noise, scale, calibration report, costs
    ENSEMBLE_DIR/member-00/ ...       one model folder per member (model.json, weights.pt)
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.errors import ModelLoadError

SCHEMA = "workbench/leg-model-ensemble@1"
#: two-sided 90 % quantile of the standard normal
Z90 = 1.6448536269514722


@dataclass
class Ensemble:
    """Members (LearnedLegModel), per-channel noise variance and calibration scale."""

    members: list
    noise_var: np.ndarray
    scale: np.ndarray
    record: dict

    @property
    def seq_len(self) -> int:
        """Longest member window."""
        return max(int(m.seq_len) for m in self.members)

    def member_predictions(self, motion) -> np.ndarray:
        """(K, B, T, 6) every member's wrench for the motion batch."""
        return np.stack([np.asarray(m.wrench(motion), dtype=np.float64) for m in self.members])

    def predict(self, motion) -> tuple[np.ndarray, np.ndarray]:
        """Mean (B, T, 6) and the variance of a reading (B, T, 6): calibrated spread plus noise."""
        preds = self.member_predictions(motion)
        return preds.mean(0), self.reading_var(preds.var(0, ddof=1))

    def reading_var(self, model_var: np.ndarray) -> np.ndarray:
        """Variance of a reading from the members' variance (per channel: scale^2 (var + noise))."""
        return self.scale**2 * (model_var + self.noise_var)

    def interval(self, motion, level: float = 0.9) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Mean, lower and upper bound of the central ``level`` interval of a reading (Gaussian)."""
        from statistics import NormalDist

        z = NormalDist().inv_cdf(0.5 + level / 2)
        mean, var = self.predict(motion)
        sd = np.sqrt(var)
        return mean, mean - z * sd, mean + z * sd


def load_ensemble(folder: str | Path) -> Ensemble:
    """Read an ensemble folder written by ``workbench train-ensemble`` (:func:`train_ensemble`'s files)."""
    from workbench.learn.legmodel import load_model, read_model_json

    folder = Path(folder)
    path = folder / "ensemble.json"
    rec = read_model_json(folder, "ensemble.json",
                          missing="no ensemble.json: not an ensemble folder (workbench train-ensemble writes one)")
    if not isinstance(rec, dict) or rec.get("schema") != SCHEMA:
        schema = rec.get("schema") if isinstance(rec, dict) else None
        raise ModelLoadError(f"unknown ensemble schema {schema!r}", path=path, hint=f"expected {SCHEMA}")
    try:
        members = [load_model(folder / m["dir"]) for m in rec["members"]]
        noise = np.array([rec["noise_var"][c] for c in WRENCH_CHANNELS], float)
        scale = np.array([rec["scale"][c] for c in WRENCH_CHANNELS], float)
    except (KeyError, TypeError) as exc:
        raise ModelLoadError(f"ensemble.json is incomplete ({type(exc).__name__}: {exc})", path=path) from None
    if len(members) < 2:
        raise ModelLoadError("an ensemble needs at least two members", path=path)
    return Ensemble(members, noise, scale, rec)


def _split_arrays(prepared, members: Sequence, name: str, skip: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Member predictions (K, N, 6), readings (N, 6) and run numbers (N,) on the measured runs of one split."""
    from workbench.learn.metrics import predict_runs

    runs = prepared.runs(name)
    table = prepared.table
    ys = [table.y[table.run_slice(int(r))].astype(np.float64)[skip:] for r in runs]
    preds = []
    for m in members:
        preds.append(np.concatenate([p[skip:] for p in predict_runs(table, runs, m)]) if len(runs) else
                     np.zeros((0, 6)))
    rid = np.concatenate([np.full(len(y), i) for i, y in enumerate(ys)]) if ys else np.zeros(0, int)
    return np.stack(preds), (np.concatenate(ys) if ys else np.zeros((0, 6))), rid


def _scores(preds: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residual noise per channel and the scores |y - mean| / sqrt(var + noise) (N, 6)."""
    mu, var = preds.mean(0), preds.var(0, ddof=1)
    mse = ((y - mu) ** 2).mean(0)
    noise = np.maximum(mse - var.mean(0), 0.01 * mse)
    return noise, np.abs(y - mu) / np.sqrt(var + noise)


#: quantile levels the leave-one-run-out search tries (finest step 0.0005)
LEVELS = np.round(np.arange(0.9, 0.99951, 0.0005), 4)


def loro_levels(z: np.ndarray, runs: np.ndarray, target: float = 0.9,
                levels: np.ndarray = LEVELS) -> tuple[np.ndarray, np.ndarray]:
    """Per channel: the smallest pooled-quantile level whose leave-one-run-out coverage is >= ``target``.

    For each level and each run, the quantile of the *other* runs' scores is the threshold and the
    held-out run's readings inside it are counted; coverage = counted / readings. Returns the
    levels (6,) and their leave-one-run-out coverage (6,); a channel that misses ``target`` even at
    the last level gets level 1 (the largest score) and the coverage reached there.
    """
    ids = np.unique(runs)
    lev, cov = np.ones(z.shape[1]), np.zeros(z.shape[1])
    for c in range(z.shape[1]):
        inside = np.zeros(len(levels))
        for r in ids:
            held = runs == r
            thr = np.quantile(z[~held, c], levels)
            inside += np.searchsorted(np.sort(z[held, c]), thr, side="right")
        frac = inside / len(z)
        ok = np.flatnonzero(frac >= target)
        if len(ok):
            lev[c], cov[c] = levels[ok[0]], frac[ok[0]]
        else:
            cov[c] = np.mean([(z[runs == r, c] <= z[runs != r, c].max()).mean() for r in ids])
    return lev, cov


def calibrate(val_preds: np.ndarray, val_y: np.ndarray, runs: np.ndarray | None = None,
              detail: dict | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel noise variance and 90 % scale fitted on the validation split (never on test).

    ``noise_c = max(mean (y - mean_k)^2 - mean var_k, 1 % of the first)``. Without ``runs`` (or
    with fewer than 3 validation runs), ``scale_c`` is the split-conformal quantile of the pooled
    scores, level ``ceil((n + 1) 0.9) / n`` for n readings. With ``runs`` (the run of each reading),
    it is the pooled quantile at the level :func:`loro_levels` finds: holding out one whole run at a
    time, the interval fitted on the others covers 90 % of the held-out readings. ``detail`` (a dict)
    receives the levels and that leave-one-run-out coverage.
    """
    noise, z = _scores(val_preds, val_y)
    n = len(z)
    if runs is None or len(np.unique(runs)) < 3:
        level = min(1.0, np.ceil((n + 1) * 0.9) / max(n, 1))
        if detail is not None:
            detail.update(level={c: level for c in WRENCH_CHANNELS})
        return noise, np.quantile(z, level, axis=0, method="inverted_cdf") / Z90
    lev, cov = loro_levels(z, runs)
    if detail is not None:
        detail.update(level=_per_channel(lev), coverage_val_loro=_per_channel(cov))
    return noise, np.array([np.quantile(z[:, c], lev[c]) for c in range(z.shape[1])]) / Z90


def run_quantile_scale(val_preds: np.ndarray, val_y: np.ndarray, runs: np.ndarray, run_level: float = 0.9):
    """The earlier rule, for comparison only: the ``run_level`` quantile over runs of each run's 90 % quantile."""
    _, z = _scores(val_preds, val_y)
    per_run = np.array([np.quantile(z[runs == r], 0.9, axis=0) for r in np.unique(runs)])
    return np.quantile(per_run, run_level, axis=0) / Z90


def coverage(preds: np.ndarray, y: np.ndarray, noise: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Fraction of readings (per channel) inside the 90 % interval."""
    mu, var = preds.mean(0), preds.var(0, ddof=1)
    sd = scale * np.sqrt(var + noise)
    return (np.abs(y - mu) <= Z90 * sd).mean(0)


def _per_channel(x) -> dict:
    return {c: float(v) for c, v in zip(WRENCH_CHANNELS, x, strict=True)}


def train_ensemble(cfg, *, members: int = 5, first_seed: int = 0, report: Callable[[str], None] | None = None,
                   split=None) -> tuple[dict, dict[str, bytes]]:
    """Train ``members`` FED-LSTMs through :func:`workbench.learn.train.train`; return the ensemble folder's content.

    ``cfg`` is the :class:`LearnSettings` every member uses (its ``trainer.seed`` is replaced by
    ``first_seed + k``; its ``model_dir`` is ignored). The data are read and split once. Returns
    ``(record, files)``: the ``ensemble.json`` record (calibration before/after, member and ensemble
    test MSE, costs) and the folder's files as bytes (``ensemble.json``, ``member-XX/model.json``,
    ``member-XX/weights.pt``), which the caller writes (``workbench train-ensemble``: atomically,
    :func:`workbench.commands.train_ensemble.write_ensemble`).
    ``split``: a :class:`~workbench.learn.split.ParameterSplit` to use instead of splitting the
    data by ``cfg.data.split`` (e.g. keep a first campaign's split and train on every later run).
    """
    from workbench.errors import ContractError
    from workbench.learn.datamodule import prepare_data
    from workbench.learn.legmodel import model_files
    from workbench.learn.train import train
    from workbench.learn.windows import read_table

    if members < 2:
        raise ContractError(f"an ensemble needs at least 2 members, got {members}")
    say = report or (lambda s: None)
    t0 = time.perf_counter()
    prepared = prepare_data(read_table(cfg.data.paths), cfg.data, split=split)
    models, member_rec = [], []
    for k in range(members):
        seed = first_seed + k
        cfg_k = cfg.with_overrides({"trainer.seed": seed, "model_dir": None})
        t_k = time.perf_counter()
        metrics, objs = train(cfg_k, prepared=prepared, score_test=False, log_model=False, kind="ensemble",
                              extra_tags={"ensemble_member": str(k)}, report=report)
        models.append(objs["model"])
        member_rec.append({"dir": f"member-{k:02d}", "seed": seed, "best_val_loss": metrics["best_val_loss"],
                           "epochs": metrics["epochs"], "stop_reason": metrics["stop_reason"],
                           "train_s": time.perf_counter() - t_k, **({"run_id": objs["run_id"]} if "run_id" in objs
                                                                     else {})})
        say(f"member {k + 1}/{members} (seed {seed}): best val loss {metrics['best_val_loss']:.4f}, "
            f"{member_rec[-1]['train_s']:.0f} s")
    t_cal = time.perf_counter()
    skip = max(m.seq_len for m in models) - 1
    val_p, val_y, val_r = _split_arrays(prepared, models, "val", skip)
    test_p, test_y, _ = _split_arrays(prepared, models, "test", skip)
    _, z_val = _scores(val_p, val_y)
    pooled = np.quantile(z_val, 0.9, axis=0) / Z90
    run90 = run_quantile_scale(val_p, val_y, val_r) if len(np.unique(val_r)) else np.ones(6)
    detail: dict = {}
    noise, scale = calibrate(val_p, val_y, val_r, detail=detail)
    ones = np.ones(6)
    rec: dict = {
        "schema": SCHEMA, "members": member_rec, "channels": list(WRENCH_CHANNELS),
        "noise_var": _per_channel(noise), "scale": _per_channel(scale),
        "interval": "mean +- 1.645 * scale * sqrt(members' variance + noise_var), per channel",
        "calibration": {
            "level": 0.9, "fitted_on": "val",
            "method": "cross-conformal by run: pooled val quantile at the smallest level whose leave-one-run-out "
                      "coverage on val is >= 90 %",
            "val_runs": int(len(np.unique(val_r))), "val_ticks": int(len(val_y)), "test_ticks": int(len(test_y)),
            "quantile_level": detail.get("level"), "coverage_val_loro": detail.get("coverage_val_loro"),
            "scale_pooled": _per_channel(pooled), "scale_run_quantile": _per_channel(run90),
            "coverage_val_before": _per_channel(coverage(val_p, val_y, noise, ones)),
            "coverage_val_after": _per_channel(coverage(val_p, val_y, noise, scale)),
            "comparison_note": "scale_pooled (val 90 % quantile) and scale_run_quantile (90 % of the readings in "
                               "90 % of the val runs) are fitted on val too; their test coverage is reported, never "
                               "used to choose",
        },
        "config": cfg.to_dict(), "split": prepared.split.to_dict(),
    }
    if len(test_y):
        mu = test_p.mean(0)
        rec["calibration"]["coverage_test_before"] = _per_channel(coverage(test_p, test_y, noise, ones))
        rec["calibration"]["coverage_test_after"] = _per_channel(coverage(test_p, test_y, noise, scale))
        rec["calibration"]["coverage_test_pooled_scale"] = _per_channel(coverage(test_p, test_y, noise, pooled))
        rec["calibration"]["coverage_test_run_quantile_scale"] = _per_channel(coverage(test_p, test_y, noise, run90))
        rec["test_mse"] = {"ensemble_mean": _per_channel(((test_y - mu) ** 2).mean(0)),
                           "members": [_per_channel(((test_y - p) ** 2).mean(0)) for p in test_p]}
        rec["test_mean_variance"] = {"members": _per_channel(test_p.var(0, ddof=1).mean(0)),
                                     "noise": _per_channel(noise)}
    rec["cost_s"] = {"train": sum(m["train_s"] for m in member_rec), "calibrate": time.perf_counter() - t_cal,
                     "total": time.perf_counter() - t0}
    files = {f"{r['dir']}/{name}": data for m, r in zip(models, member_rec, strict=True)
             for name, data in model_files(m).items()}
    files["ensemble.json"] = (json.dumps(rec, indent=2) + "\n").encode("utf-8")
    return rec, files
