"""headline.json: the loop's results in one small file for ``dvc metrics show|diff`` and ``dvc exp show``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from workbench.report.read import found, load_json, read_scores

#: channel short names in headline.json
_SHORT = {"fx_n": "fx", "fy_n": "fy", "fz_n": "fz", "tx_nm": "tx", "ty_nm": "ty", "tz_nm": "tz"}
_KEY_CHANNELS = ("fy_n", "fz_n", "tx_nm")


def headline(datasets: Path) -> dict:
    """The loop's results in one small file, so ``dvc metrics show|diff`` and ``dvc exp show`` read at a glance.

    Results only (no timings, no paths), short keys, a few numbers per step: the learned model's
    held-out MSE over the EF's on the paper's three channels (and R^2), each gait file's best score
    S, the pool's time per model and task (mean over the swum gaits; 60 = not finished) and how many
    finished, the drag fit's quadratic coefficients, the diagnosis's held-out error cut, and the
    tuning study's best validation loss. Each stage's own files keep everything. Missing results are
    left out, so the file is valid at any stage of a campaign.
    """
    out: dict[str, Any] = {}
    for section in (_leg_models, _best_scores, _pool, _drag, _diagnosis, _trajectory, _tune):
        out.update(section(datasets))
    return out


def _leg_models(datasets: Path) -> dict:
    """``lstm_over_ef_mse`` and ``r2`` on the key channels, when both models have test MSEs."""
    doc = load_json(datasets / "metrics" / "leg_models.json") or {}
    ef, lstm = doc.get("ef", {}), doc.get("lstm", {})
    if not (ef.get("mse") and lstm.get("mse")):
        return {}
    return {"lstm_over_ef_mse": {_SHORT[ch]: round(lstm["mse"][ch] / ef["mse"][ch], 4) for ch in _KEY_CHANNELS
                                 if ef["mse"].get(ch) and ch in lstm["mse"]},
            "r2": {f"{m}_{_SHORT[ch]}": round(d["r2"][ch], 4) for m, d in (("ef", ef), ("lstm", lstm))
                   for ch in _KEY_CHANNELS if ch in d.get("r2", {})}}


def _best_scores(datasets: Path) -> dict:
    """``best_S``: each gait file's best solution's score S."""
    best = {}
    for gj in found(datasets / "gaits", "*.json"):
        d = load_json(gj)
        if isinstance(d, dict) and d.get("solutions") and isinstance(d["solutions"][0].get("score"), (int, float)):
            best[gj.stem] = round(d["solutions"][0]["score"], 3)
    return {"best_S": best} if best else {}


def _pool(datasets: Path) -> dict:
    """``pool_time_s`` (mean over the timed trials) and ``pool_finished`` per task and model."""
    times: dict[str, list[float]] = {}
    finished: dict[str, int] = {}
    for sj in found(datasets / "scores", "*/summary.json"):
        for r in read_scores(sj.parent):
            key = f"{r.get('task')}_{r.get('model')}"
            pool = times.setdefault(key, [])
            if r.get("time_s"):
                pool.append(float(r["time_s"]))
            finished[key] = finished.get(key, 0) + (str(r.get("completed")).lower() == "true")
    if not times:
        return {}
    return {"pool_time_s": {k: round(sum(v) / len(v), 2) for k, v in times.items() if v}, "pool_finished": finished}


def _drag(datasets: Path) -> dict:
    """``drag_c2``: each drag fit's quadratic coefficient per heading (the demo towing fit unprefixed)."""
    c2 = {}
    for dj in found(datasets / "drag", "*/drag.json"):
        d = load_json(dj) or {}
        for h in ("forward", "lateral"):
            if isinstance(d.get(h), dict) and d[h].get("coefficients"):
                c2[h if dj.parent.name == "demo-towing" else f"{dj.parent.name}_{h}"] = round(d[h]["coefficients"][0], 4)
    return {"drag_c2": c2} if c2 else {}


def _diagnosis(datasets: Path) -> dict:
    """``diagnosis``: each diagnosis's effect count and held-out error cut (the demo EF diagnosis unprefixed)."""
    diag: dict[str, Any] = {}
    files = found(datasets / "diagnosis", "*/diagnosis.json")
    for dj in files:
        d = load_json(dj) or {}
        cut = d.get("mse_relative_reduction") or {}
        prefix = "" if dj.parent.name == "demo-tunnel-ef" else f"{dj.parent.name}_"
        diag[f"{prefix}effects"] = len(d.get("effects", []))
        diag.update({f"{prefix}cut_{_SHORT[ch]}": round(cut[ch], 4) for ch in _KEY_CHANNELS if ch in cut})
    return {"diagnosis": diag} if files else {}


def _trajectory(datasets: Path) -> dict:
    """``trajectory_rms_m``: the swum trajectories' RMS position error per model (the last file that has any)."""
    out = {}
    for tj in found(datasets / "diagnosis", "*/trajectory_errors.json"):
        models = (load_json(tj) or {}).get("models") or {}
        rms = {k.replace(" ", "_"): round(v["rms_position_m"], 3) for k, v in models.items()
               if isinstance(v, dict) and isinstance(v.get("rms_position_m"), (int, float))}
        if rms:
            out["trajectory_rms_m"] = rms
    return out


def _tune(datasets: Path) -> dict:
    """``tune_best_val_loss``: the tuning study's best validation loss."""
    best = (load_json(datasets / "models" / "tune" / "best.json") or {}).get("best") or {}
    return {"tune_best_val_loss": round(best["value"], 5)} if isinstance(best.get("value"), (int, float)) else {}
