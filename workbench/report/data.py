"""Report sections on the data and the leg models.

Campaign quality, the drag fit, EF against FED-LSTM, and the paper's 16-tick FED-LSTM beside
the 32-tick default.
"""

from __future__ import annotations

from pathlib import Path

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.report.page import Section, fmt
from workbench.report.read import found, load_json, pngs


def campaigns_section(datasets: Path) -> Section:
    """Per campaign: runs, ticks, dropped frames, clock offset/drift found, flags (ingest quality reports)."""
    sec = Section("Campaigns and data quality")
    rows = []
    for q in found(datasets / "processed", "*.quality.json"):
        doc = load_json(q) or {}
        runs = [r for r in doc.get("runs", []) if isinstance(r, dict)]
        drift = [abs(r["clock_drift_ppm"]) for r in runs if isinstance(r.get("clock_drift_ppm"), (int, float))]
        resid = [r["edge_residual_max_ms"] for r in runs if isinstance(r.get("edge_residual_max_ms"), (int, float))]
        rows.append([doc.get("campaign_id", q.stem), doc.get("facility", "?"),
                     f"{doc.get('runs_ingested', '?')}/{doc.get('runs_total', '?')}", fmt(doc.get("ticks")),
                     fmt(doc.get("dropped_frames")), fmt(max(drift) if drift else None, 1),
                     fmt(max(resid) if resid else None, 2), str(len(doc.get("runs_flagged", []) or [])),
                     str(len(doc.get("runs_saturated", []) or []))])
    if rows:
        sec.tables.append(("Ingest quality (datasets/processed/*.quality.json)",
                           ["campaign", "facility", "runs ingested", "ticks", "dropped frames",
                            "max |drift| (ppm)", "max edge residual (ms)", "runs flagged", "runs saturated"], rows))
    else:
        sec.paragraphs.append("No processed campaigns yet (run `dvc repro` or `workbench ingest`).")
    return sec


def drag_section(datasets: Path) -> Section:
    """Body drag fits with standard errors, R^2 and the physical-doubt flags."""
    sec = Section("Body drag (towing tank)")
    for dj in found(datasets / "drag", "*/drag.json"):
        doc = load_json(dj) or {}
        rows = []
        for heading in ("forward", "lateral"):
            e = doc.get(heading) or {}
            c = e.get("coefficients") or [None] * 3
            s = e.get("stderr") or [None] * 3
            rows.append([heading] + [f"{fmt(ci)} +- {fmt(si)}" for ci, si in zip(c, s, strict=False)] + [fmt(e.get("r2"), 5)])
            for flag in e.get("flags", []) or []:
                sec.paragraphs.append(f"**{dj.parent.name} {heading}:** {flag}")
        sec.tables.append((f"F = c2 v^2 + c1 v + c0 (N), {dj.parent.name}", ["heading", "c2", "c1", "c0", "R^2"], rows))
        sec.figures += pngs(dj.parent)
    if not sec.tables:
        sec.paragraphs.append("No drag fit yet.")
    return sec


def leg_models_section(datasets: Path) -> Section:
    """EF vs FED-LSTM on the held-out parameter sets (datasets/metrics/leg_models.json)."""
    sec = Section("Leg force models: EF vs FED-LSTM (held-out parameter sets)")
    doc = load_json(datasets / "metrics" / "leg_models.json")
    if not doc:
        sec.paragraphs.append("No evaluation yet.")
        return sec
    models = [m for m in doc if isinstance(doc[m], dict) and "mse" in doc[m]]
    rows = []
    for m in models:
        rows.append([m, "MSE"] + [fmt(doc[m]["mse"].get(ch)) for ch in WRENCH_CHANNELS])
        rows.append([m, "R^2"] + [fmt(doc[m].get("r2", {}).get(ch)) for ch in WRENCH_CHANNELS])
    sec.tables.append(("Per channel", ["model", "metric", *WRENCH_CHANNELS], rows))
    if "ef" in models and "lstm" in models:
        speeds = sorted(doc["ef"].get("mse_by_flow_speed", {}))
        ratio_rows = []
        for sp in speeds:
            ef = doc["ef"]["mse_by_flow_speed"].get(sp, {})
            ls = doc["lstm"].get("mse_by_flow_speed", {}).get(sp, {})
            ratio_rows.append([sp] + [fmt(ls[ch] / ef[ch]) if ef.get(ch) and ch in ls else "-"
                                      for ch in ("fy_n", "fz_n", "tx_nm")])
        sec.tables.append(("LSTM MSE / EF MSE by flow speed (target <= 0.5)", ["flow (m/s)", "fy_n", "fz_n", "tx_nm"],
                           ratio_rows))
    sec.figures += pngs(datasets / "metrics") + pngs(datasets / "reports" / "leg_models")
    return sec


def seq_len_inputs(models: list[str], *, leg_metrics_paths=(), gaits_dir: str | Path = "datasets/gaits",
                   pool_summary_path: str | Path | None = None) -> dict:
    """Read what :func:`workbench.gait.compare.seq_len_tables` compares (missing files are left out, not errors).

    ``leg_metrics_paths``: evaluate outputs, merged in order (a later file's model keys win);
    gait metrics ``<gaits_dir>/<task>-<key>.metrics.json``; the pool's summary.json. Returns the
    keyword arguments ``leg_metrics``, ``gait_metrics`` and ``pool_summary`` of ``seq_len_tables``.
    """
    from workbench.gait.compare import TASKS

    leg: dict = {}
    for p in leg_metrics_paths:
        leg.update(load_json(Path(p)) or {})
    gait = {k: {t: d for t in TASKS if (d := load_json(Path(gaits_dir) / f"{t}-{k}.metrics.json"))} for k in models}
    return {"leg_metrics": leg or None, "gait_metrics": gait,
            "pool_summary": load_json(Path(pool_summary_path)) if pool_summary_path else None}


def seq_len_section(datasets: Path) -> Section:
    """The paper's 16-tick FED-LSTM beside the 32-tick default: accuracy, the optimiser's predictions, the pool."""
    from workbench.gait.compare import seq_len_tables

    sec = Section("The paper's 16-tick FED-LSTM beside the 32-tick default")
    if not (datasets / "models" / "fed-lstm-16").is_dir() and not found(datasets / "gaits", "*-lstm16.json"):
        sec.paragraphs.append("No 16-tick model in this project (dvc.yaml stage train_16).")
        return sec
    pool = found(datasets / "scores", "*/summary.json")
    inputs = seq_len_inputs(["lstm", "lstm16"], leg_metrics_paths=[datasets / "metrics" / "leg_models.json"],
                            gaits_dir=datasets / "gaits", pool_summary_path=pool[0] if pool else None)
    tables, notes = seq_len_tables([("lstm", "FED-LSTM (32 ticks)"), ("lstm16", "FED-LSTM (16 ticks, paper)")],
                                   **inputs)
    sec.tables += tables
    sec.paragraphs += notes
    sec.figures += [p for p in (datasets / "models" / "fed-lstm-16" / "learning_curve.png",) if p.is_file()]
    return sec
