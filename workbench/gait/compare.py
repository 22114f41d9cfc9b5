"""Side by side: the FED-LSTM on 32-tick windows (the default) and on the paper's 16 (issue 14.6).

:func:`seq_len_tables` is pure: it takes what the pipeline already wrote, loaded as dicts, and
returns the report's tables (caption, header, rows); :func:`seq_len_comparison` renders them as
markdown; the report verb reads the files (``workbench.report.seq_len_inputs``). Three views of
each model, each from its own file:

* held-out accuracy: ``workbench evaluate`` metrics (``leg_models.json`` shape: per model ``mse``
  and ``r2`` per channel), best scored on the same test runs and ticks (one evaluate with
  ``--also lstm16=datasets/models/fed-lstm-16``, so both skip the same start-up ticks);
* the optimiser's own prediction: ``datasets/gaits/<task>-<model>.metrics.json`` (best f3, the
  predicted time to finish the trials' task, and best S);
* the virtual pool's measurement on the virtual truth: ``summary.json`` of ``score-trials``
  (``by_model``: per label and task, completed count and time statistics).

Anything missing shows as ``-`` with a line saying which file was not given; an unfinished
trial is never shown as a time (the 60 s cap is not a finishing time).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

from workbench.errors import SettingError

#: channels compared by default (the paper's Fig. 5 channels)
CHANNELS = ("fy_n", "fz_n", "tx_nm")
#: units of the MSE per channel
MSE_UNITS = {"fx_n": "N^2", "fy_n": "N^2", "fz_n": "N^2", "tx_nm": "(N m)^2", "ty_nm": "(N m)^2", "tz_nm": "(N m)^2"}
TASKS = ("straight", "turn")
#: the pool score shown beside the time, per task
SECOND_SCORE = {"straight": ("mae_x_m", "MAE(X) (m)"), "turn": ("radius_m", "r_T (m)")}


def _num(v) -> float | None:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _g(v, fmt: str = ".3g") -> str:
    v = _num(v)
    return "-" if v is None else format(v, fmt)


Table = tuple[str, list[str], list[list[str]]]


def seq_len_tables(models: Sequence[tuple[str, str]], *, leg_metrics: Mapping[str, Any] | None = None,
                   gait_metrics: Mapping[str, Mapping[str, Mapping[str, Any]]] | None = None,
                   pool_summary: Mapping[str, Any] | None = None, pool_labels: Mapping[str, str] | None = None,
                   channels: Sequence[str] = CHANNELS, baseline: str = "ef",
                   cap_s: float = 60.0) -> tuple[list[Table], list[str]]:
    """Learned models (e.g. 32- and 16-tick FED-LSTMs) side by side: accuracy, prediction and pool.

    Returns ``(tables, notes)``: three tables as ``(caption, header, rows)`` (the report's
    ``Section.tables`` shape) and notes naming what was not available.

    ``models``: ``(key, title)`` pairs in column order, e.g. ``[("lstm", "FED-LSTM (32 ticks)"),
    ("lstm16", "FED-LSTM (16 ticks)")]``; the key names the model in ``leg_metrics`` and
    ``gait_metrics``. ``leg_metrics``: evaluate's metrics, ``{key: {"mse": {ch: v}, "r2": {ch: v}}}``
    (``baseline``'s MSE, the EF's, is shown first when present). ``gait_metrics``:
    ``{key: {task: <task>-<key>.metrics.json}}``. ``pool_summary``: score-trials' summary.json;
    ``pool_labels``: key -> the model name in the scores (default: the virtual pool's labels,
    ``lstm`` FED-LSTM, ``lstm16`` FED-LSTM-16). ``cap_s``: the trials' time cap (a time at or above it
    is an unfinished trial).
    """
    if not models:
        raise SettingError("the comparison needs at least one model", where="models",
                           hint="give (key, title) pairs, e.g. [('lstm', 'FED-LSTM (32 ticks)')]")
    keys = [k for k, _ in models]
    titles = dict(models)
    missing: list[str] = []
    tables = [_accuracy_table(keys, titles, leg_metrics or {}, channels, baseline, missing),
              _optimiser_table(keys, titles, gait_metrics or {}, cap_s, missing),
              _pool_table(keys, titles, pool_summary, pool_labels, cap_s, missing)]
    notes = ["Not available: " + "; ".join(dict.fromkeys(missing)) + "."] if missing else []
    return tables, notes


def _accuracy_table(keys: list[str], titles: Mapping[str, str], leg: Mapping[str, Any], channels: Sequence[str],
                    baseline: str, missing: list[str]) -> Table:
    """Held-out MSE and R^2 per channel (the baseline's MSE first; the ratio of the first two models)."""
    have_base = baseline in leg and isinstance(leg[baseline], Mapping)
    head = ["channel"] + ([f"{baseline.upper()} MSE"] if have_base else [])
    for k in keys:
        head += [f"{titles[k]} MSE", f"{titles[k]} R^2"]
    if len(keys) >= 2:
        head.append(f"MSE {titles[keys[1]]} / {titles[keys[0]]}")
    rows = []
    for ch in channels:
        row = [f"{ch} ({MSE_UNITS.get(ch, '')})"]
        if have_base:
            row.append(_g(leg[baseline].get("mse", {}).get(ch)))
        for k in keys:
            m = leg.get(k) or {}
            row += [_g((m.get("mse") or {}).get(ch)), _g((m.get("r2") or {}).get(ch), ".3f")]
        if len(keys) >= 2:
            a = _num(((leg.get(keys[0]) or {}).get("mse") or {}).get(ch))
            b = _num(((leg.get(keys[1]) or {}).get("mse") or {}).get(ch))
            row.append("-" if a in (None, 0.0) or b is None else f"{b / a:.2f}")
        rows.append(row)
    absent = [k for k in keys if k not in leg]
    if absent:
        missing.append(f"no held-out metrics for {', '.join(absent)}")
    return ("Held-out accuracy (test parameter sets; MSE and R^2 per channel on the same runs and ticks)",
            head, rows)


def _optimiser_table(keys: list[str], titles: Mapping[str, str], gm: Mapping[str, Mapping[str, Any]],
                     cap_s: float, missing: list[str]) -> Table:
    """Each model's predicted best f3 and best S per task (an f3 at or above the cap: not finished)."""
    head = ["task"]
    for k in keys:
        head += [f"{titles[k]} best f3 (s)", f"{titles[k]} best S"]
    rows = []
    for task in TASKS:
        row = [task]
        for k in keys:
            m = (gm.get(k) or {}).get(task)
            if not m:
                row += ["-", "-"]
                missing.append(f"no optimiser metrics for {task}-{k}")
                continue
            f3 = _num(m.get("best_f3"))
            f3_txt = "-" if f3 is None else (f"not finished ({f3:.1f})" if f3 >= cap_s else f"{f3:.1f}")
            row += [f3_txt, _g(m.get("best_score"), ".2f")]
        rows.append(row)
    return ("Optimiser (NSGA-II): each model's own prediction for its best gait; f3 = time to finish the "
            f"trials' task (s; {cap_s:g} s or more = not finished); S = w1 f1 + w2 f2 + w3 f3, lower is "
            "better", head, rows)


def _pool_table(keys: list[str], titles: Mapping[str, str], pool_summary: Mapping[str, Any] | None,
                pool_labels: Mapping[str, str] | None, cap_s: float, missing: list[str]) -> Table:
    """The virtual pool's finished count, best and median time and median score per task and model."""
    rows = []
    by_model = (pool_summary or {}).get("by_model") or {}
    if pool_summary is None:
        missing.append("no pool summary")
    for task in TASKS:
        for k in keys:
            label = _pool_label(k, pool_labels)
            st = (by_model.get(label) or {}).get(task)
            if not st:
                rows.append([task, titles[k], "-", "-", "-", "-"])
                if pool_summary is not None:
                    missing.append(f"no pool trials of {label} ({task})")
                continue
            rows.append([task, titles[k], *_pool_cells(task, st, cap_s)])
    return ("Virtual pool: the retained gaits swum on the virtual truth and scored from video (best time "
            f"among finished trials; unfinished trials within {cap_s:g} s are counted, not timed)",
            ["task", "model", "finished", "best time (s)", "median time (s)", "median score"], rows)


def _pool_cells(task: str, st: Mapping[str, Any], cap_s: float) -> list[str]:
    """Finished/n, best time, median time and median second score of one model's trials of one task."""
    name, unit = SECOND_SCORE[task]
    n, done = int(st.get("n", 0)), int(st.get("completed", 0))
    times = st.get("time_s") or {}
    best = _num(times.get("min"))
    best_txt = "none finished" if done == 0 or best is None or best >= cap_s else f"{best:.1f}"
    med = _num(times.get("median"))
    med_txt = "-" if med is None else (f">= {cap_s:g} (unfinished)" if med >= cap_s else f"{med:.1f}")
    second = (st.get(name) or {}).get("median")
    return [f"{done}/{n}", best_txt, med_txt, f"{unit} {_g(second)}"]


def seq_len_comparison(models: Sequence[tuple[str, str]], **kwargs) -> str:
    """The same comparison as markdown (:func:`seq_len_tables` arguments): bold captions, tables, notes."""
    tables, notes = seq_len_tables(models, **kwargs)
    out: list[str] = []
    for caption, head, rows in tables:
        out += [f"**{caption}**", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        out += ["| " + " | ".join(r) + " |" for r in rows]
        out.append("")
    out += notes
    return "\n".join(out).rstrip("\n") + "\n"


def _pool_label(key: str, labels: Mapping[str, str] | None) -> str:
    if labels and key in labels:
        return labels[key]
    from workbench.virtual_lab.pool import model_display_label

    return model_display_label(key)
