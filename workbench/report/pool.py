"""Report section on the open-water trials.

Every scored trial, the improvement over the EF, the verdict per task
(:mod:`workbench.report.verdict`) and the turn trials by gait space.
"""

from __future__ import annotations

from pathlib import Path

from workbench.report.page import MODEL_LABELS, Section, fmt
from workbench.report.read import found, load_json, pngs, read_scores
from workbench.report.verdict import pool_verdict


def _trial_table(scores_dir: Path) -> tuple[str, list[str], list[list[str]]] | None:
    """Scored trials as a table: unfinished trials say so instead of showing the 60 s cap as a time."""
    rows = read_scores(scores_dir)
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
                        rows.append([task, model, agg, SCORE_NAMES.get(score, score), fmt(base), fmt(mine),
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
    for summary in found(datasets / "scores", "*/summary.json"):
        doc = load_json(summary) or {}
        for table in (_trial_table(summary.parent), _improvement_table(doc)):
            if table:
                sec.tables.append(table)
        failed = doc.get("failed") or []
        if failed:
            sec.paragraphs.append(f"**Failed trials ({summary.parent.name}):** " +
                                  "; ".join(f"{f.get('trial_id', '?')}: {f.get('error', '')}" if isinstance(f, dict)
                                            else str(f) for f in failed))
        sec.paragraphs += pool_verdict(datasets, summary.parent)
        sec.figures += [p for p in pngs(summary.parent) if "trajector" in p.name or "box" in p.name]
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
    groups = _turn_groups(datasets)
    if not any(space != "paper" for space, _ in groups):
        return None
    order = sorted(groups, key=lambda k: (k[0] != "paper", k[0], k[1]))
    rows = [_turn_row(space, groups[(space, key)]) for space, key in order]
    notes = [_space_note(space, groups) for space in sorted({s for s, _ in groups if s != "paper"})]
    return (("turn: the paper's gait space beside its extensions (virtual pool, truth physics, scored from video; "
             "60 s = not finished; predicted: the model's own time for the same gaits, gait file f3)",
             ["gait space", "model", "finished", "mean pool time (s)", "mean turn radius (m)", "predicted time (s)",
              "pool minus predicted (s)"], rows), notes)


def _mean(v):
    """The mean of a list, None when it is empty."""
    return sum(v) / len(v) if v else None


def _turn_groups(datasets: Path) -> dict[tuple[str, str], dict]:
    """Every pool folder's timed turn trials, grouped by (gait space, model key)."""
    groups: dict[tuple[str, str], dict] = {}
    for summary in found(datasets / "scores", "*/summary.json"):
        truth = load_json(datasets / "raw" / summary.parent.name / "truth.json") or {}
        labels = dict(MODEL_LABELS) | ((truth.get("settings") or {}).get("model_labels") or {})
        for r in read_scores(summary.parent):
            if r.get("task") == "turn" and r.get("time_s"):
                _add_turn_trial(groups, datasets, r, labels, summary.parent.name)
    return groups


def _add_turn_trial(groups: dict, datasets: Path, r: dict, labels: dict[str, str], pool: str) -> None:
    """Add one scored turn trial (time, finished, radius, the model's predicted time) to its group."""
    key = _trial_key(r, labels)
    gait = load_json(datasets / "gaits" / f"turn-{key}.json") or {}
    space = str(gait.get("gait_space") or "paper")
    g = groups.setdefault((space, key), {"label": r.get("model", key), "time": [], "done": 0, "radius": [],
                                         "predicted": [], "pool": pool})
    g["time"].append(float(r["time_s"]))
    g["done"] += str(r.get("completed")).lower() == "true"
    if r.get("radius_m"):
        g["radius"].append(float(r["radius_m"]))
    g["predicted"].append(_predicted_time(gait, r))


def _predicted_time(gait: dict, r: dict) -> float | None:
    """The time the gait file's model predicted for the trial's solution (its f3), None when unknown."""
    sols = {int(x.get("rank", 0)): x for x in gait.get("solutions") or []}
    sol = sols.get(int(r["solution"])) if str(r.get("solution", "")).isdigit() else None
    f3 = ((sol or {}).get("objectives") or {}).get("f3")
    return float(f3) if isinstance(f3, (int, float)) else None


def _group_prediction(g: dict) -> float | None:
    """A group's mean predicted time, None when any of its trials has no prediction."""
    return None if None in g["predicted"] else _mean(g["predicted"])


def _turn_row(space: str, g: dict) -> list[str]:
    """One table row: finished, mean pool time, mean radius, predicted time and the difference."""
    pred = _group_prediction(g)
    t = _mean(g["time"])
    return [space, g["label"], f"{g['done']}/{len(g['time'])}", fmt(t, 1), fmt(_mean(g["radius"]), 3),
            fmt(pred, 1), "-" if pred is None else f"{t - pred:+.1f}"]


def _space_note(space: str, groups: dict[tuple[str, str], dict]) -> str:
    """The paragraph on one extended gait space: its models' results beside the paper's space, and the verdict."""
    mine = {k: groups[(s, k)] for s, k in groups if s == space}
    text = "; ".join(f"{g['label']} {g['done']}/{len(g['time'])} finished, mean {_mean(g['time']):.1f} s"
                     for g in mine.values())
    paper_done = sum(g["done"] for (s, _), g in groups.items() if s == "paper")
    paper_n = sum(len(g["time"]) for (s, _), g in groups.items() if s == "paper")
    ef = next((g for k, g in mine.items() if k.startswith("ef")), None)
    ls = next((g for k, g in mine.items() if k.startswith("lstm") and not k[4:5].isdigit()), None)
    return (f"**turn in the {space} gait space** (pool folder {next(iter(mine.values()))['pool']}): "
            f"{text} (the paper's space: {paper_done}/{paper_n} turn trials finished).{_space_verdict(ef, ls)}")


def _space_verdict(ef: dict | None, ls: dict | None) -> str:
    """Whether the FED-LSTM's gaits beat the EF's in the pool, and whose own prediction came closer ("" without both)."""
    if not (ef and ls):
        return ""
    te, tl = _mean(ef["time"]), _mean(ls["time"])
    verdict = (" Neither model's gaits finished." if not (ef["done"] or ls["done"]) else
               f" {ls['label']} gaits {'beat' if tl < te else 'do not beat'} {ef['label']} gaits on the "
               f"virtual truth ({tl:.1f} s against {te:.1f} s).")
    pe, pl = (_group_prediction(g) for g in (ef, ls))
    if pe is not None and pl is not None:
        closer = ls if abs(tl - pl) < abs(te - pe) else ef
        verdict += (f" Predicted by their own models: {ls['label']} {pl:.1f} s, {ef['label']} {pe:.1f} s "
                    f"(pool minus prediction {tl - pl:+.1f} s and {te - pe:+.1f} s): the "
                    f"{closer['label']} prediction is the closer one on these gaits.")
    return verdict
