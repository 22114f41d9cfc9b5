"""The pool verdict: did the FED-LSTM's gaits beat the EF's in the pool, and why not where they did not."""

from __future__ import annotations

from pathlib import Path

from workbench.report.page import MODEL_LABELS
from workbench.report.read import load_json, read_scores

#: the trials' protocol (data contract section 2): what a gait file's task must match to be comparable
TRIAL_PROTOCOL = {"straight": {"cap_s": 60.0, "finish_distance_m": 2.0}, "turn": {"cap_s": 60.0, "target_yaw_deg": 360.0}}


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
    rows = read_scores(scores_dir)
    if not rows:
        return []
    labels = dict(MODEL_LABELS)
    truth = load_json(datasets / "raw" / scores_dir.name / "truth.json") or {}
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
    gait = load_json(datasets / "gaits" / f"{task}-{key}.json") or {}
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
