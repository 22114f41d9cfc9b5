"""Report sections on the optimised gaits.

The best gait of each task and model, and the sensitivity of the gait scores and ranking to the
estimated robot constants.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from workbench.report.page import MODEL_LABELS, Section, fmt
from workbench.report.read import found, load_json, pngs

#: the optimiser's objectives per task: (name, unit) of f1, f2, f3 (docs/gaits.md; lower is better)
OBJECTIVES = {
    "straight": (("-Y impulse f1", "N s"), ("heading error f2", "rad"), ("time to 2 m f3", "s")),
    "turn": (("path length f1", "m"), ("yaw short of 360 deg f2", "rad"), ("time to 360 deg f3", "s")),
}


def gaits_section(datasets: Path) -> Section:
    """Best retained gait of each task and model, objectives named per task, and the optimisation plots."""
    sec = Section("Optimised gaits (NSGA-II)")
    by_task: dict[str, list[list[str]]] = {}
    for gj in found(datasets / "gaits", "*.json"):
        doc = load_json(gj)
        if not isinstance(doc, dict) or "solutions" not in doc or not doc["solutions"]:
            continue
        best = doc["solutions"][0]
        p, o = best.get("params", {}), best.get("objectives", {})
        alpha = p.get("alpha_rad", [])
        cap = ((doc.get("settings") or {}).get("task") or {}).get("cap_s", 60.0)
        f3 = o.get("f3")
        f3_text = (fmt(f3, 2) if not isinstance(f3, (int, float)) or f3 < float(cap) - 1e-9
                   else f"not finished within {float(cap):g} s")
        unconv = doc.get("unconverged_gaits")
        by_task.setdefault(doc.get("task", "?"), []).append(
            [_model_label(doc.get("model", "?")), str(len(doc["solutions"])),
             _fmt_legs(p.get("theta_h_min_deg"), 1), _fmt_legs(p.get("theta_k_max_deg"), 1),
             fmt(p.get("frequency_hz"), 3),
             ", ".join(fmt(a, 2) for a in alpha), fmt(o.get("f1")), fmt(o.get("f2")), f3_text,
             fmt(best.get("score")), "-" if unconv is None else str(unconv)])
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
    sec.figures += pngs(datasets / "gaits")
    return sec


def _model_label(key: str) -> str:
    """The pool's name of a gait file's model (``ef`` EF, ``lstm-sides`` FED-LSTM-sides, ...)."""
    from workbench.virtual_lab.pool_settings import model_display_label

    return model_display_label(key, MODEL_LABELS)


def _fmt_legs(v: Any, digits: int) -> str:
    """A gait parameter: one value, or per leg (LF, RF, LH, RH) when the legs differ."""
    if isinstance(v, list):
        return fmt(float(v[0]), digits) if len(set(v)) == 1 else " / ".join(fmt(float(x), digits) for x in v)
    return fmt(v, digits)


def sensitivity_section(datasets: Path) -> Section:
    """How much the robot constants the paper does not give move the gait scores and ranking (Sobol)."""
    sec = Section("Sensitivity to the estimated robot constants")
    for sj in found(datasets / "reports" / "sensitivity", "*/sensitivity.json"):
        doc = load_json(sj) or {}
        factors = [f.get("name") for f in doc.get("factors", []) if isinstance(f, dict)]
        indices = doc.get("indices") or {}
        gait_keys = [k for k, v in indices.items() if v and k != "ranking_kendall_tau"]
        rank = indices.get("ranking_kendall_tau") or {}
        rows = []
        for f in doc.get("factors", []):
            name = f.get("name")
            st = [indices[k]["total_order"].get(name) for k in gait_keys]
            st = [v for v in st if isinstance(v, (int, float))]
            rows.append([name, f"{fmt(f.get('low'))}-{fmt(f.get('high'))} {f.get('unit', '')}".strip(),
                         fmt(sum(st) / len(st)) if st else "-", fmt(max(st)) if st else "-",
                         fmt((rank.get("total_order") or {}).get(name))])
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
            f"**{sj.parent.name}:** ranking against the nominal robot: Kendall tau {fmt(r.get('kendall_tau_mean'), 2)} "
            f"on average (worst {fmt(r.get('kendall_tau_min'), 2)}); the nominal best gait stays best in "
            f"{100 * float(r.get('nominal_best_stays_best_fraction') or 0):.0f} % of the samples. "
            f"The scores depend most on {top[0]}: measure it first (docs/sensitivity.md says how)."
            + (f" Unconverged samples (not scored): {sum(len(v) for v in unconv.values())}." if unconv else ""))
        sec.figures += [p for p in [sj.parent / "sensitivity.png"] if p.is_file()]
    if not sec.tables:
        sec.paragraphs.append("No sensitivity study yet (workbench sensitivity; docs/sensitivity.md).")
    return sec
