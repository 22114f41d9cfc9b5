"""Report sections on the model diagnosis.

The effects found and the error they remove, and the trajectory error of the leg models against
the tracked pool trials.
"""

from __future__ import annotations

from pathlib import Path

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.report.page import Section, fmt
from workbench.report.read import found, load_json, pngs


def diagnosis_section(datasets: Path) -> Section:
    """Residual diagnosis: effects found with parameters, error before and after, what stays unexplained."""
    sec = Section("Closing the loop: model diagnosis")
    for dj in found(datasets / "diagnosis", "*/diagnosis.json"):
        doc = load_json(dj) or {}
        chans = doc.get("channels", list(WRENCH_CHANNELS))
        before, after = doc.get("mse_before", {}), doc.get("mse_after", {})
        sec.tables.append((f"{dj.parent.name}: held-out MSE of model '{doc.get('model', '?')}' before and after",
                           ["", *chans], [["before"] + [fmt(before.get(c)) for c in chans],
                                          ["after"] + [fmt(after.get(c)) for c in chans]]))
        eff_rows = [[e.get("name", "?"), ", ".join(e.get("channels", [])),
                     ", ".join(f"{k}={fmt(v)}" for k, v in (e.get("params") or {}).items()),
                     fmt(e.get("heldout_mse_reduction")), e.get("evidence", "")] for e in doc.get("effects", [])]
        if eff_rows:
            sec.tables.append(("Effects added (best first)",
                               ["effect", "channels", "parameters", "held-out MSE reduction", "evidence"], eff_rows))
        budget = doc.get("selection_budget") or {}
        if budget.get("converged") is False and budget.get("note"):
            sec.paragraphs.append(f"**Not converged:** {budget['note']}.")
        for note in (doc.get("fit_convergence") or {}).get("notes", []):
            sec.paragraphs.append(f"**Not converged:** {note}.")
        for u in doc.get("unexplained", []) or []:
            sec.paragraphs.append(f"**Unexplained ({u.get('kind', '?')})** in {', '.join(u.get('channels', []))}"
                                  + (f" at {fmt(u.get('frequency_hz'), 2)} Hz" if u.get("frequency_hz") else "")
                                  + f": {u.get('evidence', '')}")
        sec.figures += pngs(dj.parent, limit=6)
    if not sec.tables:
        sec.paragraphs.append("No diagnosis yet.")
    return sec


def trajectory_section(datasets: Path) -> Section:
    """Trajectory error of the leg models against the tracked pool trials (diagnose --trials)."""
    from workbench.diagnose.trajectory import errors_rows

    sec = Section("Trajectory error: EF, augmented EF, FED-LSTM side by side")
    for tj in found(datasets / "diagnosis", "*/trajectory_errors.json"):
        doc = load_json(tj) or {}
        header, rows = errors_rows(doc)
        sec.tables.append((f"{tj.parent.name}: the pool trials swum again in the simulator with each leg model, "
                           "against the tracks scored from the videos (converged swims only; tracks cut at the "
                           f"wall: {', '.join(doc.get('cut_at_wall') or []) or 'none'})", header, rows))
        for model, d in (doc.get("models") or {}).items():
            for e in (d.get("effects") or []) if isinstance(d, dict) else []:
                sec.paragraphs.append(f"**{model}: {e.get('name', '?')}** "
                                      + ", ".join(f"{k}={fmt(v)}" for k, v in (e.get("params") or {}).items()))
        sec.figures += [p for p in [tj.parent / "trajectory_errors.png"] if p.is_file()]
    if not sec.tables:
        sec.paragraphs.append("No trajectory diagnosis yet (workbench diagnose --trials; docs/diagnose-trajectory.md).")
    return sec
