"""The final report: campaign quality, drag fit, EF-vs-LSTM accuracy, gaits, trial scores, diagnosis.

:func:`collect` reads the pipeline's result files (the data contract's section 5 and each
stage's own summaries) into plain dicts; :func:`render_markdown` and :func:`render_html` turn
them into a page whose figures are the stages' own PNGs (linked relative to the report, so the
report folder stays small) with links to the MLflow runs behind each step.
"""

from __future__ import annotations

import html
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from workbench.contract.columns import WRENCH_CHANNELS

#: the pipeline's MLflow experiments in the order the data flows (others in the store follow by name)
MLFLOW_EXPERIMENTS = ("fed-lstm", "fed-lstm-tune", "evaluate", "optimize", "diagnose")


@dataclass
class Section:
    """One part of the report: a title, paragraphs, tables and figures."""

    title: str
    paragraphs: list[str] = field(default_factory=list)
    #: tables as (caption, header, rows)
    tables: list[tuple[str, list[str], list[list[str]]]] = field(default_factory=list)
    #: figures as paths (captioned by :func:`caption`) or (path, caption)
    figures: list[Path | tuple[Path, str]] = field(default_factory=list)
    links: list[tuple[str, str]] = field(default_factory=list)


#: what each stage's figure shows, by file name; "{what}" is filled from the folder (task and model)
FIGURE_CAPTIONS = {
    "drag.png": "Towing-tank drag force against towing speed with the quadratic fit and its residuals ({what})",
    "hypervolume.png": "Hypervolume of the Pareto front after each NSGA-II generation ({what}; higher is better)",
    "pareto.png": "Final Pareto front of the three objectives, retained gaits marked ({what})",
    "trajectories.png": "Simulated 60 s paths of the retained gaits, start at the origin ({what})",
    "mse_boxplot.png": "Held-out MSE per run, EF against the learned model, per channel (N^2 for forces, "
                       "(N m)^2 for torques; log scale)",
    "prediction_a.png": "Measured and predicted wrench over the last cycles of a held-out run (the paper's Fig. 4 set a)",
    "prediction_b.png": "Measured and predicted wrench over the last cycles of a held-out run (the paper's Fig. 4 set b)",
    "sensitivity.png": "Total Sobol indices of the estimated robot constants for each retained gait's score and "
                       "for the ranking ({what})",
    "boxplots.png": "Pool-trial scores per model and task (unfinished trials drawn apart, not as 60 s times)",
    "learning_curve.png": "Training and validation loss per epoch ({what})",
    "trajectory_errors.png": "RMS position and heading error of each leg model's swims against the tracked pool "
                             "trials, each trial in its own frame",
}


def _what(path: Path) -> str:
    """A figure's subject from its folder name: ``straight-lstm`` -> ``straight task, FED-LSTM``."""
    name = path.parent.name
    if name in ("plots",):
        name = path.parent.parent.name
    task, _, model = name.partition("-")
    if task in ("straight", "turn") and model:
        return f"{task} task, {MODEL_LABELS.get(model, model)}"
    return name


def caption(path: Path) -> str:
    """The caption of a stage figure: what it shows, not its file name."""
    if path.parent.name == "plots" and path.name == "trajectories.png":
        return f"Pool trajectories scored from the overhead videos, per model and task ({path.parent.parent.name})"
    text = FIGURE_CAPTIONS.get(path.name)
    if text is None:
        return path.stem.replace("_", " ").capitalize() + f" ({_what(path)})"
    return text.format(what=_what(path))


def _figure(f: Path | tuple[Path, str]) -> tuple[Path, str]:
    return (f[0], f[1]) if isinstance(f, tuple) else (f, caption(f))


def _load_json(path: Path) -> Any | None:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None


def _fmt(v: Any, digits: int = 3) -> str:
    if v is None or v == "":
        return "-"
    if isinstance(v, float):
        if v != 0 and (abs(v) < 1e-3 or abs(v) >= 1e5):
            return f"{v:.{digits}e}"
        return f"{v:.{digits}f}"
    return str(v)


def _pngs(folder: Path, limit: int = 12) -> list[Path]:
    if not folder.is_dir():
        return []
    return sorted(folder.rglob("*.png"))[:limit]


def campaigns_section(datasets: Path) -> Section:
    """Per campaign: runs, ticks, dropped frames, clock offset/drift found, flags (ingest quality reports)."""
    sec = Section("Campaigns and data quality")
    rows = []
    for q in sorted((datasets / "processed").glob("*.quality.json")):
        doc = _load_json(q) or {}
        runs = [r for r in doc.get("runs", []) if isinstance(r, dict)]
        drift = [abs(r["clock_drift_ppm"]) for r in runs if isinstance(r.get("clock_drift_ppm"), (int, float))]
        resid = [r["edge_residual_max_ms"] for r in runs if isinstance(r.get("edge_residual_max_ms"), (int, float))]
        rows.append([doc.get("campaign_id", q.stem), doc.get("facility", "?"),
                     f"{doc.get('runs_ingested', '?')}/{doc.get('runs_total', '?')}", _fmt(doc.get("ticks")),
                     _fmt(doc.get("dropped_frames")), _fmt(max(drift) if drift else None, 1),
                     _fmt(max(resid) if resid else None, 2), str(len(doc.get("runs_flagged", []) or [])),
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
    for dj in sorted((datasets / "drag").glob("*/drag.json")):
        doc = _load_json(dj) or {}
        rows = []
        for heading in ("forward", "lateral"):
            e = doc.get(heading) or {}
            c = e.get("coefficients") or [None] * 3
            s = e.get("stderr") or [None] * 3
            rows.append([heading] + [f"{_fmt(ci)} +- {_fmt(si)}" for ci, si in zip(c, s, strict=False)] + [_fmt(e.get("r2"), 5)])
            for flag in e.get("flags", []) or []:
                sec.paragraphs.append(f"**{dj.parent.name} {heading}:** {flag}")
        sec.tables.append((f"F = c2 v^2 + c1 v + c0 (N), {dj.parent.name}", ["heading", "c2", "c1", "c0", "R^2"], rows))
        sec.figures += _pngs(dj.parent)
    if not sec.tables:
        sec.paragraphs.append("No drag fit yet.")
    return sec


def leg_models_section(datasets: Path) -> Section:
    """EF vs FED-LSTM on the held-out parameter sets (datasets/metrics/leg_models.json)."""
    sec = Section("Leg force models: EF vs FED-LSTM (held-out parameter sets)")
    doc = _load_json(datasets / "metrics" / "leg_models.json")
    if not doc:
        sec.paragraphs.append("No evaluation yet.")
        return sec
    models = [m for m in doc if isinstance(doc[m], dict) and "mse" in doc[m]]
    rows = []
    for m in models:
        rows.append([m, "MSE"] + [_fmt(doc[m]["mse"].get(ch)) for ch in WRENCH_CHANNELS])
        rows.append([m, "R^2"] + [_fmt(doc[m].get("r2", {}).get(ch)) for ch in WRENCH_CHANNELS])
    sec.tables.append(("Per channel", ["model", "metric", *WRENCH_CHANNELS], rows))
    if "ef" in models and "lstm" in models:
        speeds = sorted(doc["ef"].get("mse_by_flow_speed", {}))
        ratio_rows = []
        for sp in speeds:
            ef = doc["ef"]["mse_by_flow_speed"].get(sp, {})
            ls = doc["lstm"].get("mse_by_flow_speed", {}).get(sp, {})
            ratio_rows.append([sp] + [_fmt(ls[ch] / ef[ch]) if ef.get(ch) and ch in ls else "-"
                                      for ch in ("fy_n", "fz_n", "tx_nm")])
        sec.tables.append(("LSTM MSE / EF MSE by flow speed (target <= 0.5)", ["flow (m/s)", "fy_n", "fz_n", "tx_nm"],
                           ratio_rows))
    sec.figures += _pngs(datasets / "metrics") + _pngs(datasets / "reports" / "leg_models")
    return sec


#: the optimiser's objectives per task: (name, unit) of f1, f2, f3 (docs/gaits.md; lower is better)
OBJECTIVES = {
    "straight": (("-Y impulse f1", "N s"), ("heading error f2", "rad"), ("time to 2 m f3", "s")),
    "turn": (("path length f1", "m"), ("yaw short of 360 deg f2", "rad"), ("time to 360 deg f3", "s")),
}


def gaits_section(datasets: Path) -> Section:
    """Best retained gait of each task and model, objectives named per task, and the optimisation plots."""
    sec = Section("Optimised gaits (NSGA-II)")
    by_task: dict[str, list[list[str]]] = {}
    for gj in sorted((datasets / "gaits").glob("*.json")):
        doc = _load_json(gj)
        if not isinstance(doc, dict) or "solutions" not in doc or not doc["solutions"]:
            continue
        best = doc["solutions"][0]
        p, o = best.get("params", {}), best.get("objectives", {})
        alpha = p.get("alpha_rad", [])
        cap = ((doc.get("settings") or {}).get("task") or {}).get("cap_s", 60.0)
        f3 = o.get("f3")
        f3_text = (_fmt(f3, 2) if not isinstance(f3, (int, float)) or f3 < float(cap) - 1e-9
                   else f"not finished within {float(cap):g} s")
        unconv = doc.get("unconverged_gaits")
        by_task.setdefault(doc.get("task", "?"), []).append(
            [_model_label(doc.get("model", "?")), str(len(doc["solutions"])),
             _fmt_legs(p.get("theta_h_min_deg"), 1), _fmt_legs(p.get("theta_k_max_deg"), 1),
             _fmt(p.get("frequency_hz"), 3),
             ", ".join(_fmt(a, 2) for a in alpha), _fmt(o.get("f1")), _fmt(o.get("f2")), f3_text,
             _fmt(best.get("score")), "-" if unconv is None else str(unconv)])
    for task, rows in by_task.items():
        names = OBJECTIVES.get(task, (("f1", ""), ("f2", ""), ("f3", "s")))
        sec.tables.append((f"{task}: best gait of each model (datasets/gaits/{task}-*.json; a -sides model's gaits "
                           "have a joint range per side, listed LF, RF, LH, RH); S = w1 f1 + w2 f2 + w3 f3, "
                           "lower is better",
                           ["model", "gaits kept", "theta_h_min (deg)", "theta_k_max (deg)", "f (Hz)",
                            "alpha LF, RF, LH, RH (rad)"] + [f"{n} ({u})" for n, u in names]
                           + ["S", "unconverged gaits in search"], rows))
    if not by_task:
        sec.paragraphs.append("No gaits yet.")
    sec.figures += _pngs(datasets / "gaits")
    return sec


def _model_label(key: str) -> str:
    """The pool's name of a gait file's model (``ef`` EF, ``lstm-sides`` FED-LSTM-sides, ...)."""
    from workbench.virtual_lab.pool_settings import model_display_label

    return model_display_label(key, MODEL_LABELS)


def _fmt_legs(v: Any, digits: int) -> str:
    """A gait parameter: one value, or per leg (LF, RF, LH, RH) when the legs differ."""
    if isinstance(v, list):
        return _fmt(float(v[0]), digits) if len(set(v)) == 1 else " / ".join(_fmt(float(x), digits) for x in v)
    return _fmt(v, digits)


def _trial_table(scores_dir: Path) -> tuple[str, list[str], list[list[str]]] | None:
    """Scored trials as a table: unfinished trials say so instead of showing the 60 s cap as a time."""
    rows = _read_scores(scores_dir)
    if not rows:
        return None
    out = []
    for r in sorted(rows, key=lambda r: (r.get("task", ""), r.get("model", ""), r.get("solution", ""))):
        done = str(r.get("completed")).lower() == "true"
        t = r.get("time_s") or ""
        time_text = f"{float(t):.1f}" if done and t else "not finished within 60 s"
        extra = (f"MAE(X) {float(r['mae_x_m']):.3f} m" if r.get("mae_x_m") else
                 f"radius {float(r['radius_m']):.3f} m" if r.get("radius_m") else "-")
        out.append([r.get("task", "?"), r.get("model", "?"), r.get("solution", "?"), time_text, extra])
    return (f"{scores_dir.name}: every scored trial (T: time to 2 m or to 360 deg, s; MAE(X): mean lateral "
            "deviation on the straight; radius: turn radius)", ["task", "model", "gait rank", "T (s)", "path"], out)


SCORE_NAMES = {"time_s": "T (s)", "mae_x_m": "MAE(X) (m)", "radius_m": "turn radius (m)"}


def _improvement_table(summary: dict) -> tuple[str, list[str], list[list[str]]] | None:
    comp = (summary.get("comparison") or {}).get("models") or {}
    rows = []
    for model, tasks in comp.items():
        for task, stats in tasks.items():
            for agg in ("best", "mean", "median"):
                for score, v in (stats.get(agg) or {}).items():
                    if isinstance(v, dict) and "improvement" in v:
                        base, mine = v.get(summary.get("comparison", {}).get("baseline", "EF")), v.get(model)
                        unfinished = (score == "time_s" and isinstance(base, (int, float))
                                      and isinstance(mine, (int, float)) and min(base, mine) >= 60.0 - 1e-9)
                        imp = v.get("improvement")
                        rows.append([task, model, agg, SCORE_NAMES.get(score, score), _fmt(base), _fmt(mine),
                                     "neither finished" if unfinished else
                                     f"{100 * float(imp):+.1f} %" if isinstance(imp, (int, float)) else "-"])
    if not rows:
        return None
    base = str((summary.get("comparison") or {}).get("baseline") or "EF")
    return (f"Improvement over {base}, ({base} - model) / {base}: positive is better (unfinished trials count as the "
            "60 s cap)", ["task", "model", "over", "score", base, "model", "improvement"], rows)


def trials_section(datasets: Path) -> Section:
    """Pool-trial scores per model and task, the improvement over the EF, and the verdict per task."""
    sec = Section("Open-water trials")
    for summary in sorted((datasets / "scores").glob("*/summary.json")):
        doc = _load_json(summary) or {}
        for table in (_trial_table(summary.parent), _improvement_table(doc)):
            if table:
                sec.tables.append(table)
        failed = doc.get("failed") or []
        if failed:
            sec.paragraphs.append(f"**Failed trials ({summary.parent.name}):** " +
                                  "; ".join(f"{f.get('trial_id', '?')}: {f.get('error', '')}" if isinstance(f, dict)
                                            else str(f) for f in failed))
        sec.paragraphs += pool_verdict(datasets, summary.parent)
        sec.figures += [p for p in _pngs(summary.parent) if "trajector" in p.name or "box" in p.name]
    spaces = turn_spaces(datasets)
    if spaces:
        sec.tables.append(spaces[0])
        sec.paragraphs += spaces[1]
    if not sec.paragraphs and not sec.figures and not sec.tables:
        sec.paragraphs.append("No trial scores yet.")
    return sec


def _trial_key(row: dict, labels: dict[str, str]) -> str:
    """The gait file's model of a scored trial: from the pool's trial id (``<model>-<task>-<rank>``), else the label."""
    tid, tail = row.get("trial_id", ""), f"-{row.get('task')}-{row.get('solution')}"
    if tid.endswith(tail) and len(tid) > len(tail):
        return tid[: -len(tail)]
    by_label = {v: k for k, v in labels.items()}
    return by_label.get(row.get("model", ""), str(row.get("model", "")).lower())


def turn_spaces(datasets: Path) -> tuple[tuple[str, list[str], list[list[str]]], list[str]] | None:
    """Turn trials of every pool folder by gait space (the paper's, per_side_range) and model, beside the predictions.

    Per (gait space, model): trials finished within 60 s, mean pool time (60 s = not finished), mean
    scored turn radius, and the mean time the model predicted for the same gaits (the gait file's f3).
    Returns the table and one paragraph per extended space (None when no gait space but the paper's was swum).
    """
    groups: dict[tuple[str, str], dict] = {}
    for summary in sorted((datasets / "scores").glob("*/summary.json")):
        truth = _load_json(datasets / "raw" / summary.parent.name / "truth.json") or {}
        labels = dict(MODEL_LABELS) | ((truth.get("settings") or {}).get("model_labels") or {})
        for r in _read_scores(summary.parent):
            if r.get("task") != "turn" or not r.get("time_s"):
                continue
            key = _trial_key(r, labels)
            gait = _load_json(datasets / "gaits" / f"turn-{key}.json") or {}
            space = str(gait.get("gait_space") or "paper")
            g = groups.setdefault((space, key), {"label": r.get("model", key), "time": [], "done": 0, "radius": [],
                                                 "predicted": [], "pool": summary.parent.name})
            g["time"].append(float(r["time_s"]))
            g["done"] += str(r.get("completed")).lower() == "true"
            if r.get("radius_m"):
                g["radius"].append(float(r["radius_m"]))
            sols = {int(x.get("rank", 0)): x for x in gait.get("solutions") or []}
            sol = sols.get(int(r["solution"])) if str(r.get("solution", "")).isdigit() else None
            f3 = ((sol or {}).get("objectives") or {}).get("f3")
            g["predicted"].append(float(f3) if isinstance(f3, (int, float)) else None)
    if not any(space != "paper" for space, _ in groups):
        return None

    def mean(v):
        return sum(v) / len(v) if v else None

    rows, notes = [], []
    order = sorted(groups, key=lambda k: (k[0] != "paper", k[0], k[1]))
    for space, key in order:
        g = groups[(space, key)]
        pred = None if None in g["predicted"] else mean(g["predicted"])
        t = mean(g["time"])
        rows.append([space, g["label"], f"{g['done']}/{len(g['time'])}", _fmt(t, 1), _fmt(mean(g["radius"]), 3),
                     _fmt(pred, 1), "-" if pred is None else f"{t - pred:+.1f}"])
    for space in sorted({s for s, _ in groups if s != "paper"}):
        mine = {k: groups[(s, k)] for s, k in groups if s == space}
        text = "; ".join(f"{g['label']} {g['done']}/{len(g['time'])} finished, mean {mean(g['time']):.1f} s"
                         for g in mine.values())
        paper_done = sum(g["done"] for (s, _), g in groups.items() if s == "paper")
        paper_n = sum(len(g["time"]) for (s, _), g in groups.items() if s == "paper")
        ef = next((g for k, g in mine.items() if k.startswith("ef")), None)
        ls = next((g for k, g in mine.items() if k.startswith("lstm") and not k[4:5].isdigit()), None)
        verdict = ""
        if ef and ls:
            te, tl = mean(ef["time"]), mean(ls["time"])
            verdict = (" Neither model's gaits finished." if not (ef["done"] or ls["done"]) else
                       f" {ls['label']} gaits {'beat' if tl < te else 'do not beat'} {ef['label']} gaits on the "
                       f"virtual truth ({tl:.1f} s against {te:.1f} s).")
            pe, pl = (None if None in g["predicted"] else mean(g["predicted"]) for g in (ef, ls))
            if pe is not None and pl is not None:
                closer = ls if abs(tl - pl) < abs(te - pe) else ef
                verdict += (f" Predicted by their own models: {ls['label']} {pl:.1f} s, {ef['label']} {pe:.1f} s "
                            f"(pool minus prediction {tl - pl:+.1f} s and {te - pe:+.1f} s): the "
                            f"{closer['label']} prediction is the closer one on these gaits.")
        notes.append(f"**turn in the {space} gait space** (pool folder {next(iter(mine.values()))['pool']}): "
                     f"{text} (the paper's space: {paper_done}/{paper_n} turn trials finished).{verdict}")
    return (("turn: the paper's gait space beside its extensions (virtual pool, truth physics, scored from video; "
             "60 s = not finished; predicted: the model's own time for the same gaits, gait file f3)",
             ["gait space", "model", "finished", "mean pool time (s)", "mean turn radius (m)", "predicted time (s)",
              "pool minus predicted (s)"], rows), notes)


#: the trials' protocol (data contract section 2): what a gait file's task must match to be comparable
TRIAL_PROTOCOL = {"straight": {"cap_s": 60.0, "finish_distance_m": 2.0}, "turn": {"cap_s": 60.0, "target_yaw_deg": 360.0}}
#: pool labels of the pipeline's model keys (the virtual pool's truth.json says so too)
MODEL_LABELS = {"ef": "EF", "lstm": "FED-LSTM", "lstm16": "FED-LSTM-16"}


def _read_scores(scores_dir: Path) -> list[dict]:
    import csv

    try:
        with open(scores_dir / "scores.csv", newline="", encoding="utf-8") as fh:
            return list(csv.DictReader(fh))
    except OSError:
        return []


def _protocol_mismatch(task: str, settings: dict) -> str | None:
    """How a gait file's optimised task differs from the trials' protocol, or None when it is the same."""
    want = TRIAL_PROTOCOL.get(task, {})
    diffs = [f"{k} {settings[k]:g} instead of {v:g}" for k, v in want.items()
             if isinstance(settings.get(k), (int, float)) and abs(float(settings[k]) - v) > 1e-9]
    return ", ".join(diffs) or None


def pool_verdict(datasets: Path, scores_dir: Path) -> list[str]:
    """Per task: did the FED-LSTM's gaits beat the EF's in the pool, and why not where they did not.

    The pool scores say which gaits swam better; the gait files say what each model predicted for
    the same gaits (f3 is the predicted time to finish the trials' task). Where the FED-LSTM's gaits
    lose, the cause is read from those numbers: gaits optimised for another task than the one judged,
    a model whose prediction of its own gaits misses the pool's time (model error on the states the
    gaits visit), or a model that predicted its own gaits slower (the optimiser found no better gait).
    """
    rows = _read_scores(scores_dir)
    if not rows:
        return []
    labels = dict(MODEL_LABELS)
    truth = _load_json(datasets / "raw" / scores_dir.name / "truth.json") or {}
    labels.update((truth.get("settings") or {}).get("model_labels") or {})
    out = []
    for task in ("straight", "turn"):
        per_model = {}
        for key, label in labels.items():
            stats = _pool_stats(datasets, task, key, label, rows)
            if stats is not None:
                per_model[key] = stats
        if {"ef", "lstm"} <= set(per_model):
            out.append(_task_verdict(task, per_model["lstm"], per_model["ef"]))
    return out


def _pool_stats(datasets: Path, task: str, key: str, label: str, rows: list[dict]) -> dict | None:
    """One model's pool trials of one task beside its gait file: mean time, finished, mean predicted f3.

    None when the model has no timed trial of the task; ``predicted`` is None unless every trial's
    gait has a predicted f3; ``mismatch`` says how the gaits' optimised task differs from the trials'.
    """
    gait = _load_json(datasets / "gaits" / f"{task}-{key}.json") or {}
    sols = {int(s.get("rank", i + 1)): s for i, s in enumerate(gait.get("solutions") or [])}
    trials = [r for r in rows if r.get("task") == task and r.get("model") == label and r.get("time_s")]
    if not trials:
        return None
    achieved = [float(r["time_s"]) for r in trials]
    predicted = [sols[int(r["solution"])]["objectives"].get("f3") for r in trials
                 if r.get("solution", "").isdigit() and int(r["solution"]) in sols]
    predicted = [float(p) for p in predicted if isinstance(p, (int, float))]
    return {"label": label, "n": len(trials), "achieved": sum(achieved) / len(achieved),
            "completed": sum(str(r.get("completed")).lower() == "true" for r in trials),
            "predicted": sum(predicted) / len(predicted) if len(predicted) == len(trials) else None,
            "mismatch": _protocol_mismatch(task, ((gait.get("settings") or {}).get("task") or {}))}


def _task_verdict(task: str, ls: dict, ef: dict) -> str:
    """The paragraph for one task: FED-LSTM (``ls``) against EF gaits in the pool, and why."""
    better = ls["achieved"] < ef["achieved"]
    neither = not ls["completed"] and not ef["completed"]
    verdict = ("neither model's gaits finished the task within 60 s" if neither else
               f"FED-LSTM gaits {'beat' if better else 'do not beat'} EF gaits on the virtual truth")
    text = (f"**{task}: {verdict}.** "
            f"Mean pool time {ls['achieved']:.1f} s ({ls['completed']}/{ls['n']} finished) against "
            f"{ef['achieved']:.1f} s ({ef['completed']}/{ef['n']}); 60 s means not finished.")
    reasons = []
    for m in (ls, ef):
        if m["mismatch"]:
            reasons.append(f"the {m['label']} gaits were optimised for another task than the trials' "
                           f"({m['mismatch']}), so their predicted times do not compare with the pool's")
    if neither and task == "turn":
        reasons.append("in the paper's gait space (one hip and knee range for all legs, only the phases free) "
                       "the legs' mean yaw torque cancels to first order, so its gaits turn at a few deg/s "
                       "while 360 degrees in 60 s needs 6 deg/s (docs/gaits.md; the per_side_range extension "
                       "of the gait space turns)")
    if not (ls["mismatch"] or ef["mismatch"]) and ls["predicted"] is not None and ef["predicted"] is not None:
        gap = {"lstm": ls["achieved"] - ls["predicted"], "ef": ef["achieved"] - ef["predicted"]}
        text += (f" Predicted by their own models: FED-LSTM {ls['predicted']:.1f} s, EF {ef['predicted']:.1f} s "
                 f"(pool minus prediction: {gap['lstm']:+.1f} s and {gap['ef']:+.1f} s).")
        reasons += _prediction_reasons(ls, ef, gap, neither, better)
    if better and reasons:
        text += " Caveat: " + "; ".join(reasons) + "."
    if not better or neither:
        text += " Why: " + ("; ".join(reasons) if reasons else
                            "not determined from the gait files (the predictions agree with the pool; the "
                            "difference is within the two models' own ranking)") + "."
    return text


def _prediction_reasons(ls: dict, ef: dict, gap: dict[str, float], neither: bool, better: bool) -> list[str]:
    """What the models' predictions of their own gaits say about a loss (or a task neither finished)."""
    reasons = []
    if neither:
        for m in (ls, ef):
            if m["predicted"] < 60.0:
                reasons.append(f"the {m['label']} predicted its gaits to finish in {m['predicted']:.1f} s: "
                               "it overrates them on the virtual truth")
    elif not better:
        if ls["predicted"] >= ef["predicted"]:
            reasons.append("the FED-LSTM predicted its own gaits no faster than the EF predicted its gaits: "
                           "the optimiser found no better gait under the learned model (search budget, or "
                           "the learned model is pessimistic on the states these gaits visit)")
        if gap["lstm"] > max(gap["ef"], 0.0) + 1.0:
            reasons.append(f"the FED-LSTM is {gap['lstm']:.1f} s optimistic about its own gaits on the truth, "
                           f"the EF {gap['ef']:.1f} s: its error on the states these gaits visit (outside "
                           "the tunnel campaign's parameter sets or flow speeds) outweighs its held-out accuracy")
    return reasons


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
        leg.update(_load_json(Path(p)) or {})
    gait = {k: {t: d for t in TASKS if (d := _load_json(Path(gaits_dir) / f"{t}-{k}.metrics.json"))} for k in models}
    return {"leg_metrics": leg or None, "gait_metrics": gait,
            "pool_summary": _load_json(Path(pool_summary_path)) if pool_summary_path else None}


def seq_len_section(datasets: Path) -> Section:
    """The paper's 16-tick FED-LSTM beside the 32-tick default: accuracy, the optimiser's predictions, the pool."""
    from workbench.gait.compare import seq_len_tables

    sec = Section("The paper's 16-tick FED-LSTM beside the 32-tick default")
    if not (datasets / "models" / "fed-lstm-16").is_dir() and not list((datasets / "gaits").glob("*-lstm16.json")):
        sec.paragraphs.append("No 16-tick model in this project (dvc.yaml stage train_16).")
        return sec
    pool = sorted((datasets / "scores").glob("*/summary.json"))
    inputs = seq_len_inputs(["lstm", "lstm16"], leg_metrics_paths=[datasets / "metrics" / "leg_models.json"],
                            gaits_dir=datasets / "gaits", pool_summary_path=pool[0] if pool else None)
    tables, notes = seq_len_tables([("lstm", "FED-LSTM (32 ticks)"), ("lstm16", "FED-LSTM (16 ticks, paper)")],
                                   **inputs)
    sec.tables += tables
    sec.paragraphs += notes
    sec.figures += [p for p in (datasets / "models" / "fed-lstm-16" / "learning_curve.png",) if p.is_file()]
    return sec


def sensitivity_section(datasets: Path) -> Section:
    """How much the robot constants the paper does not give move the gait scores and ranking (Sobol)."""
    sec = Section("Sensitivity to the estimated robot constants")
    for sj in sorted((datasets / "reports" / "sensitivity").glob("*/sensitivity.json")):
        doc = _load_json(sj) or {}
        factors = [f.get("name") for f in doc.get("factors", []) if isinstance(f, dict)]
        indices = doc.get("indices") or {}
        gait_keys = [k for k, v in indices.items() if v and k != "ranking_kendall_tau"]
        rank = indices.get("ranking_kendall_tau") or {}
        rows = []
        for f in doc.get("factors", []):
            name = f.get("name")
            st = [indices[k]["total_order"].get(name) for k in gait_keys]
            st = [v for v in st if isinstance(v, (int, float))]
            rows.append([name, f"{_fmt(f.get('low'))}-{_fmt(f.get('high'))} {f.get('unit', '')}".strip(),
                         _fmt(sum(st) / len(st)) if st else "-", _fmt(max(st)) if st else "-",
                         _fmt((rank.get("total_order") or {}).get(name))])
        if not factors:
            continue
        r = doc.get("ranking") or {}
        sec.tables.append((f"{sj.parent.name}: total Sobol index (ST) of each factor, {doc.get('task', '?')} gaits, "
                           f"{doc.get('n_simulations', '?')} simulations",
                           ["factor", "range", "ST of gait scores (mean)", "ST (max)", "ST of ranking (Kendall tau)"],
                           rows))
        top = max(rows, key=lambda row: float(row[2]) if row[2] != "-" else -1.0)
        unconv = doc.get("unconverged_samples") or {}
        sec.paragraphs.append(
            f"**{sj.parent.name}:** ranking against the nominal robot: Kendall tau {_fmt(r.get('kendall_tau_mean'), 2)} "
            f"on average (worst {_fmt(r.get('kendall_tau_min'), 2)}); the nominal best gait stays best in "
            f"{100 * float(r.get('nominal_best_stays_best_fraction') or 0):.0f} % of the samples. "
            f"The scores depend most on {top[0]}: measure it first (docs/sensitivity.md says how)."
            + (f" Unconverged samples (not scored): {sum(len(v) for v in unconv.values())}." if unconv else ""))
        sec.figures += [p for p in [sj.parent / "sensitivity.png"] if p.is_file()]
    if not sec.tables:
        sec.paragraphs.append("No sensitivity study yet (workbench sensitivity; docs/sensitivity.md).")
    return sec


def diagnosis_section(datasets: Path) -> Section:
    """Residual diagnosis: effects found with parameters, error before and after, what stays unexplained."""
    sec = Section("Closing the loop: model diagnosis")
    for dj in sorted((datasets / "diagnosis").glob("*/diagnosis.json")):
        doc = _load_json(dj) or {}
        chans = doc.get("channels", list(WRENCH_CHANNELS))
        before, after = doc.get("mse_before", {}), doc.get("mse_after", {})
        sec.tables.append((f"{dj.parent.name}: held-out MSE of model '{doc.get('model', '?')}' before and after",
                           ["", *chans], [["before"] + [_fmt(before.get(c)) for c in chans],
                                          ["after"] + [_fmt(after.get(c)) for c in chans]]))
        eff_rows = [[e.get("name", "?"), ", ".join(e.get("channels", [])),
                     ", ".join(f"{k}={_fmt(v)}" for k, v in (e.get("params") or {}).items()),
                     _fmt(e.get("heldout_mse_reduction")), e.get("evidence", "")] for e in doc.get("effects", [])]
        if eff_rows:
            sec.tables.append(("Effects added (best first)",
                               ["effect", "channels", "parameters", "held-out MSE reduction", "evidence"], eff_rows))
        for u in doc.get("unexplained", []) or []:
            sec.paragraphs.append(f"**Unexplained ({u.get('kind', '?')})** in {', '.join(u.get('channels', []))}"
                                  + (f" at {_fmt(u.get('frequency_hz'), 2)} Hz" if u.get("frequency_hz") else "")
                                  + f": {u.get('evidence', '')}")
        sec.figures += _pngs(dj.parent, limit=6)
    if not sec.tables:
        sec.paragraphs.append("No diagnosis yet.")
    return sec


def trajectory_section(datasets: Path) -> Section:
    """Trajectory error of the leg models against the tracked pool trials (diagnose --trials)."""
    from workbench.diagnose.trajectory import errors_rows

    sec = Section("Trajectory error: EF, augmented EF, FED-LSTM side by side")
    for tj in sorted((datasets / "diagnosis").glob("*/trajectory_errors.json")):
        doc = _load_json(tj) or {}
        header, rows = errors_rows(doc)
        sec.tables.append((f"{tj.parent.name}: the pool trials swum again in the simulator with each leg model, "
                           "against the tracks scored from the videos (converged swims only; tracks cut at the "
                           f"wall: {', '.join(doc.get('cut_at_wall') or []) or 'none'})", header, rows))
        for model, d in (doc.get("models") or {}).items():
            for e in (d.get("effects") or []) if isinstance(d, dict) else []:
                sec.paragraphs.append(f"**{model}: {e.get('name', '?')}** "
                                      + ", ".join(f"{k}={_fmt(v)}" for k, v in (e.get("params") or {}).items()))
        sec.figures += [p for p in [tj.parent / "trajectory_errors.png"] if p.is_file()]
    if not sec.tables:
        sec.paragraphs.append("No trajectory diagnosis yet (workbench diagnose --trials; docs/diagnose-trajectory.md).")
    return sec


def mlflow_section(tracking_uri: str | None, ui_url: str) -> Section:
    """Links to the latest MLflow run of each pipeline step (open with `workbench ui`)."""
    sec = Section("MLflow runs")
    try:
        from mlflow.tracking import MlflowClient

        from workbench.project import mlflow_tracking_uri

        client = MlflowClient(tracking_uri=mlflow_tracking_uri(tracking_uri))
        order = {name: i for i, name in enumerate(MLFLOW_EXPERIMENTS)}
        exps = sorted(client.search_experiments(), key=lambda e: (order.get(e.name, len(order)), e.name))
        for exp in exps:
            runs = client.search_runs([exp.experiment_id], order_by=["attributes.start_time DESC"], max_results=5)
            for r in runs:
                label = f"{exp.name}: {r.info.run_name} ({r.info.status.lower()})"
                sec.links.append((label, f"{ui_url}/#/experiments/{exp.experiment_id}/runs/{r.info.run_id}"))
    except Exception as exc:  # a report without links is still a report
        sec.paragraphs.append(f"MLflow store not readable: {type(exc).__name__}: {exc}")
    if not sec.links and not sec.paragraphs:
        sec.paragraphs.append("No MLflow runs yet.")
    sec.paragraphs.append(f"Start the UI with `workbench ui`, then open {ui_url}.")
    return sec


def collect(datasets: Path, tracking_uri: str | None = None, ui_url: str = "http://127.0.0.1:5000",
            with_mlflow: bool = True) -> list[Section]:
    """All report sections, in the order the data flows through the workbench."""
    secs = [campaigns_section(datasets), drag_section(datasets), leg_models_section(datasets),
            gaits_section(datasets), sensitivity_section(datasets), trials_section(datasets), seq_len_section(datasets),
            diagnosis_section(datasets), trajectory_section(datasets)]
    if with_mlflow:
        secs.append(mlflow_section(tracking_uri, ui_url))
    return secs


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
    doc = _load_json(datasets / "metrics" / "leg_models.json") or {}
    ef, lstm = doc.get("ef", {}), doc.get("lstm", {})
    if ef.get("mse") and lstm.get("mse"):
        out["lstm_over_ef_mse"] = {_SHORT[ch]: round(lstm["mse"][ch] / ef["mse"][ch], 4) for ch in _KEY_CHANNELS
                                   if ef["mse"].get(ch) and ch in lstm["mse"]}
        out["r2"] = {f"{m}_{_SHORT[ch]}": round(d["r2"][ch], 4) for m, d in (("ef", ef), ("lstm", lstm))
                     for ch in _KEY_CHANNELS if ch in d.get("r2", {})}
    for gj in sorted((datasets / "gaits").glob("*.json")):
        d = _load_json(gj)
        if isinstance(d, dict) and d.get("solutions") and isinstance(d["solutions"][0].get("score"), (int, float)):
            out.setdefault("best_S", {})[gj.stem] = round(d["solutions"][0]["score"], 3)
    for sj in sorted((datasets / "scores").glob("*/summary.json")):
        rows = _read_scores(sj.parent)
        for r in rows:
            key = f"{r.get('task')}_{r.get('model')}"
            pool = out.setdefault("pool_time_s", {}).setdefault(key, [])
            if r.get("time_s"):
                pool.append(float(r["time_s"]))
            out.setdefault("pool_finished", {}).setdefault(key, 0)
            out["pool_finished"][key] += str(r.get("completed")).lower() == "true"
    if "pool_time_s" in out:
        out["pool_time_s"] = {k: round(sum(v) / len(v), 2) for k, v in out["pool_time_s"].items() if v}
    for dj in sorted((datasets / "drag").glob("*/drag.json")):
        d = _load_json(dj) or {}
        for h in ("forward", "lateral"):
            if isinstance(d.get(h), dict) and d[h].get("coefficients"):
                out.setdefault("drag_c2", {})[h if dj.parent.name == "demo-towing" else f"{dj.parent.name}_{h}"] = (
                    round(d[h]["coefficients"][0], 4))
    for dj in sorted((datasets / "diagnosis").glob("*/diagnosis.json")):
        d = _load_json(dj) or {}
        cut = d.get("mse_relative_reduction") or {}
        prefix = "" if dj.parent.name == "demo-tunnel-ef" else f"{dj.parent.name}_"
        diag = out.setdefault("diagnosis", {})
        diag[f"{prefix}effects"] = len(d.get("effects", []))
        diag.update({f"{prefix}cut_{_SHORT[ch]}": round(cut[ch], 4) for ch in _KEY_CHANNELS if ch in cut})
    for tj in sorted((datasets / "diagnosis").glob("*/trajectory_errors.json")):
        models = (_load_json(tj) or {}).get("models") or {}
        rms = {k.replace(" ", "_"): round(v["rms_position_m"], 3) for k, v in models.items()
               if isinstance(v, dict) and isinstance(v.get("rms_position_m"), (int, float))}
        if rms:
            out["trajectory_rms_m"] = rms
    best = (_load_json(datasets / "models" / "tune" / "best.json") or {}).get("best") or {}
    if isinstance(best.get("value"), (int, float)):
        out["tune_best_val_loss"] = round(best["value"], 5)
    return out


def _rel(path: Path, out_dir: Path) -> str:
    return Path(os.path.relpath(path.resolve(), out_dir.resolve())).as_posix()


def render_markdown(sections: list[Section], out_dir: Path, title: str = "Workbench report") -> str:
    """The report as markdown, figure links relative to ``out_dir``."""
    lines = [f"# {title}", ""]
    for s in sections:
        lines += [f"## {s.title}", ""]
        for p in s.paragraphs:
            lines += [p, ""]
        for caption, header, rows in s.tables:
            lines += [f"*{caption}*", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            lines += ["| " + " | ".join(str(c).replace("|", "/") for c in r) + " |" for r in rows]
            lines.append("")
        for f in s.figures:
            path, cap = _figure(f)
            lines += [f"![{cap}]({_rel(path, out_dir)})", "", f"*Figure: {cap}.*", ""]
        for label, url in s.links:
            lines.append(f"- [{label}]({url})")
        if s.links:
            lines.append("")
    return "\n".join(lines)


def render_html(sections: list[Section], out_dir: Path, title: str = "Workbench report") -> str:
    """The report as one HTML page (no scripts, no network), figures linked relative to ``out_dir``."""
    import re

    def md_inline(text: str) -> str:
        t = html.escape(text)
        t = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", t)
        return re.sub(r"`(.+?)`", r"<code>\1</code>", t)

    out = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
           "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em}"
           "table{border-collapse:collapse;margin:.5em 0 1.5em}td,th{border:1px solid #ccc;padding:3px 8px;"
           "font-size:90%}th{background:#f3f3f3}img{max-width:100%;margin:.5em 0;border:1px solid #eee}"
           "pre{white-space:pre-wrap}</style></head><body>", f"<h1>{html.escape(title)}</h1>"]
    out.append("<p>" + " &middot; ".join(f"<a href='#s{i}'>{html.escape(s.title)}</a>"
                                          for i, s in enumerate(sections)) + "</p>")
    for i, s in enumerate(sections):
        out.append(f"<h2 id='s{i}'>{html.escape(s.title)}</h2>")
        for p in s.paragraphs:
            out.append(f"<pre>{md_inline(p)}</pre>" if "\n" in p else f"<p>{md_inline(p)}</p>")
        for caption, header, rows in s.tables:
            out.append(f"<table><caption>{html.escape(caption)}</caption><tr>"
                       + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>")
            out += ["<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows]
            out.append("</table>")
        for f in s.figures:
            path, cap = _figure(f)
            out.append(f"<figure><img src='{html.escape(_rel(path, out_dir))}' alt='{html.escape(cap)}'>"
                       f"<figcaption>{html.escape(cap)}</figcaption></figure>")
        if s.links:
            out.append("<ul>" + "".join(f"<li><a href='{html.escape(u)}'>{html.escape(lbl)}</a></li>"
                                        for lbl, u in s.links) + "</ul>")
    out.append("</body></html>")
    return "\n".join(out)
