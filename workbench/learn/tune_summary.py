"""What a study reports: progress lines, the summary of a command's trials, ``best.json`` and ``trials.csv`` as bytes.

A command counts only its own trials (their ``command`` user attribute); a failed trial that was
retried counts by its retry. Nothing here writes a file: ``workbench tune --out`` writes
:func:`tune_files` through ``workbench/atomic.py``.
"""

from __future__ import annotations

import csv
import io
import json
from typing import Callable


def command_trials(trials, command: str | None, baseline: set[int] = frozenset()) -> list:
    """The trials a command ran (its ``command`` user attribute; without an id: those not in ``baseline``)."""
    if command is None:
        return [t for t in trials if t.number not in baseline]
    return [t for t in trials if t.user_attrs.get("command") == command]


def finished_trials(trials) -> list:
    """COMPLETE, PRUNED or FAIL trials, less failed ones that were retried (their retry counts instead)."""
    import optuna

    from workbench.learn.tune_storage import retried_numbers

    S = optuna.trial.TrialState
    retried = retried_numbers(trials)
    return [t for t in trials if t.state in (S.COMPLETE, S.PRUNED, S.FAIL)
            and not (t.state == S.FAIL and t.number in retried)]


def progress_callback(total: int, baseline: set[int], report: Callable[[str], None], tag: str,
                      command: str | None = None):
    """An Optuna callback printing one line per finished trial of this command, with the study's best so far."""
    import optuna

    def callback(study, trial):
        everything = study.get_trials(deepcopy=False)
        trials = finished_trials(everything)
        done = len(command_trials(trials, command, baseline))
        complete = [t for t in trials if t.state == optuna.trial.TrialState.COMPLETE]
        best = min(complete, key=lambda t: t.value) if complete else None
        state = trial.state.name.lower()
        if trial.state == optuna.trial.TrialState.PRUNED and trial.intermediate_values:
            last = max(trial.intermediate_values)
            value = f"at epoch {last + 1} (val {trial.intermediate_values[last]:.4f})"
        else:
            value = f"val {trial.value:.4f}" if trial.value is not None else ""
        params = ", ".join(f"{k}={_fmt(v)}" for k, v in trial.params.items())
        best_s = f"best {best.value:.4f} (trial {best.number})" if best else "no complete trial yet"
        report(f"trial {done}/{total}{tag}: #{trial.number} {state} {value} [{params}]  {best_s}")

    return callback


def _fmt(v) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def summarise(study, baseline: set[int], elapsed_s: float = 0.0, command: str | None = None) -> dict:
    """Counts, the best trial and one row per trial of this invocation (and the study's overall best).

    This invocation's trials are those with its ``command`` id (or, without one, those not in
    ``baseline``); a failed trial that was retried is counted by its retry.
    """
    import optuna

    trials = study.get_trials(deepcopy=False)
    from workbench.learn.tune_storage import retried_numbers

    retried = retried_numbers(trials)
    mine = [t for t in command_trials(trials, command, baseline) if t.number not in retried]
    counts = {s.name: sum(1 for t in mine if t.state == s) for s in optuna.trial.TrialState}
    complete = [t for t in trials if t.state == optuna.trial.TrialState.COMPLETE]
    best = min(complete, key=lambda t: t.value) if complete else None
    fails = [t.system_attrs.get("fail_reason", "?") for t in mine if t.state == optuna.trial.TrialState.FAIL]
    rows = [{"number": t.number, "state": t.state.name, "value": t.value, "params": t.params,
             "command": t.user_attrs.get("command"), "worker": t.user_attrs.get("worker"),
             "retry_of": t.system_attrs.get("failed_trial"),
             "epochs": len(t.intermediate_values), "duration_s": t.duration.total_seconds() if t.duration else None,
             "mlflow_run_id": t.user_attrs.get("mlflow_run_id")} for t in trials]
    best_d = None
    if best is not None:
        over = [f"{_param_keys().get(k, k)}={v}" for k, v in best.params.items()]
        best_d = {"number": best.number, "value": best.value, "params": best.params, "overrides": over,
                  "mlflow_run_id": best.user_attrs.get("mlflow_run_id")}
    return {"study": study.study_name, "n_trials_total": len(trials), "n_trials_this_run": len(mine),
            "counts": counts, "best": best_d, "first_failure": fails[0] if fails else None,
            "elapsed_s": elapsed_s, "trials": rows}


def tune_files(summary: dict) -> dict[str, bytes]:
    """``best.json`` (best trial, its ``--set`` overrides, counts) and ``trials.csv`` (one row per trial) as bytes."""
    best = {k: summary[k] for k in ("study", "storage", "n_trials_total", "n_trials_this_run", "counts", "best")}
    buf = io.StringIO()
    names = sorted({k for r in summary["trials"] for k in r["params"]})
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["number", "state", "value", "epochs", "duration_s", *names, "mlflow_run_id"])
    for r in summary["trials"]:
        w.writerow([r["number"], r["state"], "" if r["value"] is None else r["value"], r["epochs"],
                    "" if r["duration_s"] is None else f"{r['duration_s']:.2f}",
                    *[r["params"].get(n, "") for n in names], r["mlflow_run_id"] or ""])
    return {"best.json": (json.dumps(best, indent=2) + "\n").encode("utf-8"), "trials.csv": buf.getvalue().encode("utf-8")}


def _param_keys() -> dict[str, str]:
    from workbench.learn.tune import PARAM_KEYS

    return PARAM_KEYS
