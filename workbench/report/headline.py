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
    doc = load_json(datasets / "metrics" / "leg_models.json") or {}
    ef, lstm = doc.get("ef", {}), doc.get("lstm", {})
    if ef.get("mse") and lstm.get("mse"):
        out["lstm_over_ef_mse"] = {_SHORT[ch]: round(lstm["mse"][ch] / ef["mse"][ch], 4) for ch in _KEY_CHANNELS
                                   if ef["mse"].get(ch) and ch in lstm["mse"]}
        out["r2"] = {f"{m}_{_SHORT[ch]}": round(d["r2"][ch], 4) for m, d in (("ef", ef), ("lstm", lstm))
                     for ch in _KEY_CHANNELS if ch in d.get("r2", {})}
    for gj in found(datasets / "gaits", "*.json"):
        d = load_json(gj)
        if isinstance(d, dict) and d.get("solutions") and isinstance(d["solutions"][0].get("score"), (int, float)):
            out.setdefault("best_S", {})[gj.stem] = round(d["solutions"][0]["score"], 3)
    for sj in found(datasets / "scores", "*/summary.json"):
        rows = read_scores(sj.parent)
        for r in rows:
            key = f"{r.get('task')}_{r.get('model')}"
            pool = out.setdefault("pool_time_s", {}).setdefault(key, [])
            if r.get("time_s"):
                pool.append(float(r["time_s"]))
            out.setdefault("pool_finished", {}).setdefault(key, 0)
            out["pool_finished"][key] += str(r.get("completed")).lower() == "true"
    if "pool_time_s" in out:
        out["pool_time_s"] = {k: round(sum(v) / len(v), 2) for k, v in out["pool_time_s"].items() if v}
    for dj in found(datasets / "drag", "*/drag.json"):
        d = load_json(dj) or {}
        for h in ("forward", "lateral"):
            if isinstance(d.get(h), dict) and d[h].get("coefficients"):
                out.setdefault("drag_c2", {})[h if dj.parent.name == "demo-towing" else f"{dj.parent.name}_{h}"] = (
                    round(d[h]["coefficients"][0], 4))
    for dj in found(datasets / "diagnosis", "*/diagnosis.json"):
        d = load_json(dj) or {}
        cut = d.get("mse_relative_reduction") or {}
        prefix = "" if dj.parent.name == "demo-tunnel-ef" else f"{dj.parent.name}_"
        diag = out.setdefault("diagnosis", {})
        diag[f"{prefix}effects"] = len(d.get("effects", []))
        diag.update({f"{prefix}cut_{_SHORT[ch]}": round(cut[ch], 4) for ch in _KEY_CHANNELS if ch in cut})
    for tj in found(datasets / "diagnosis", "*/trajectory_errors.json"):
        models = (load_json(tj) or {}).get("models") or {}
        rms = {k.replace(" ", "_"): round(v["rms_position_m"], 3) for k, v in models.items()
               if isinstance(v, dict) and isinstance(v.get("rms_position_m"), (int, float))}
        if rms:
            out["trajectory_rms_m"] = rms
    best = (load_json(datasets / "models" / "tune" / "best.json") or {}).get("best") or {}
    if isinstance(best.get("value"), (int, float)):
        out["tune_best_val_loss"] = round(best["value"], 5)
    return out
