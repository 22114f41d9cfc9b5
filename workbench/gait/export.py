"""What an optimisation leaves behind, as plain data: the gait file, the controller file, the tables.

* :func:`gait_document` — ``datasets/gaits/<task>-<model>.json`` exactly per data contract
  section 5 (``task``, ``model``, ``solutions`` best score first with ``rank``, ``params``,
  ``objectives`` f1..f3 and ``score``), plus extra keys readers may ignore (objective names,
  weights, settings, seed, model spec and description).
* :func:`controller_document` — the file a robot controller loads: per retained gait and per leg
  (LF, RF, LH, RH) the two joint-angle functions ``angle_deg(t) = offset_deg + amplitude_deg *
  sin(2 pi frequency_hz t + phase_rad)`` (paper eq. 3 rewritten with a positive amplitude) and one
  cycle sampled at the controller's rate. docs/gaits.md documents the format.
"""

from __future__ import annotations

import math
import re
from typing import Any, Mapping, Sequence

import numpy as np

from workbench.gait.objectives import TaskSpec
from workbench.hydro.robot import LEG_NAMES
from workbench.hydro.simulator import GaitBatch

CONTROLLER_SCHEMA = "workbench/gait-controller@1"
GAITS_SCHEMA = "workbench/gaits@1"


def model_label(spec: str) -> str:
    """A file-name-safe label for a model spec: ``ef``, ``lstm``, ``models:/fed-lstm@tuned`` -> ``fed-lstm-tuned``.

    A saved model folder (a spec that is an existing path) is named by its last component:
    ``datasets/models/fed-lstm-16`` -> ``fed-lstm-16``; ``workbench optimize --label`` names it otherwise.
    """
    from pathlib import Path

    if spec.startswith("models:/"):
        body = spec[len("models:/"):]
    elif ("/" in spec or "\\" in spec) and ":" not in spec and Path(spec).exists():
        p = Path(spec)
        body = (p.parent if p.name == "model.json" else p).resolve().name
    else:
        body = spec
    label = re.sub(r"[^a-z0-9_-]+", "-", body.lower()).strip("-")
    return label or "model"


def model_source(model) -> dict:
    """Where a loaded leg model came from, read from its ``describe()``; {} for built-in models.

    Keys, those known: ``model_uri``, ``model_version`` and ``run_id`` (a registry spec, resolved to
    the version used) and ``model_path`` (a saved folder).
    """
    d = model.describe() if hasattr(model, "describe") else {}
    return {k: str(d[k]) for k in ("model_uri", "model_version", "run_id", "model_path") if d.get(k) is not None}


def model_source_line(spec: str, model) -> str | None:
    """One line for people: the registry version (or the folder) ``spec`` resolved to; None for built-in models."""
    p = model_source(model)
    if p.get("model_version"):
        uri = p.get("model_uri", spec)
        name = uri[len("models:/"):].split("@")[0].split("/")[0] if uri.startswith("models:/") else uri
        return (f"leg model {spec!r}: {uri} -> registered model {name} version {p['model_version']}"
                + (f" (run {p['run_id']})" if p.get("run_id") else ""))
    if p.get("model_path"):
        return f"leg model {spec!r}: model folder {p['model_path']}" + (f" (trained in run {p['run_id']})"
                                                                       if p.get("run_id") else "")
    if p.get("model_uri"):
        return f"leg model {spec!r}: {p['model_uri']}"
    return None


def gait_document(spec: TaskSpec, model: str, gaits: GaitBatch, f: np.ndarray, s: np.ndarray, *,
                  extra: Mapping[str, Any] | None = None, converged: np.ndarray | None = None,
                  gait_space: str = "paper") -> dict:
    """The contract gait file (section 5) for retained gaits already sorted best score first.

    Each solution also says whether its simulation ``converged`` (an added key; an unconverged one
    is kept only when too few converged, ranked after all that did).
    """
    params = gaits.to_params()
    solutions = []
    for i, p in enumerate(params):
        solutions.append({
            "rank": i + 1,
            "params": {"theta_h_min_deg": p["theta_h_min_deg"], "theta_k_max_deg": p["theta_k_max_deg"],
                       "frequency_hz": p["frequency_hz"], "alpha_rad": p["alpha_rad"]},
            "objectives": {"f1": float(f[i, 0]), "f2": float(f[i, 1]), "f3": float(f[i, 2])},
            "score": float(s[i]),
            "converged": True if converged is None else bool(converged[i]),
        })
    doc = {"task": spec.task, "model": model, "solutions": solutions,
           "schema": GAITS_SCHEMA, "gait_space": gait_space, "objective_names": spec.names, "weights": list(spec.weights),
           "fixed": {"theta_h_max_deg": gaits.theta_h_max_deg, "theta_k_min_deg": gaits.theta_k_min_deg,
                     "phi_rad": gaits.phi_rad}}
    doc.update(dict(extra or {}))
    return doc


def joint_functions(gaits: GaitBatch, i: int) -> dict:
    """Per leg of gait ``i``: HFE and KFE as offset + amplitude sin(2 pi f t + phase), amplitude >= 0."""
    legs = {}
    for j, leg in enumerate(LEG_NAMES):
        alpha = float(gaits.alpha_rad[i, j])
        joints = {}
        for joint, lo, hi, extra in (
                ("hfe", float(gaits.theta_h_min_deg[i, j]), gaits.theta_h_max_deg, 0.0),
                ("kfe", gaits.theta_k_min_deg, float(gaits.theta_k_max_deg[i, j]), gaits.phi_rad)):
            amp = (hi - lo) / 2  # eq. 3: (max - min) / 2 with min/max as the paper names them
            phase = alpha + extra
            if amp < 0:  # a negative amplitude is a positive one half a cycle later
                amp, phase = -amp, phase + math.pi
            joints[joint] = {"offset_deg": (hi + lo) / 2, "amplitude_deg": amp,
                             "phase_rad": float(np.mod(phase, 2 * math.pi))}
        legs[leg] = joints
    return legs


def controller_document(spec: TaskSpec, model: str, gaits: GaitBatch, s: np.ndarray, *, sample_rate_hz: float,
                        haa_deg: Sequence[float], gait_space: str = "paper") -> dict:
    """The controller gait file: every retained gait as joint-angle functions per leg plus one sampled cycle."""
    out = []
    for i in range(len(gaits)):
        f = float(gaits.frequency_hz[i])
        n = max(2, int(round(sample_rate_hz / f)))
        t = np.arange(n) / sample_rate_hz
        th, tk = gaits.rows([i]).sinusoid().evaluate(t)[:2]
        table: dict[str, Any] = {"dt_s": 1.0 / sample_rate_hz, "time_s": [round(v, 6) for v in t.tolist()]}
        for j, leg in enumerate(LEG_NAMES):
            table[leg] = {"hfe_deg": [round(v, 4) for v in th[0, j].tolist()],
                          "kfe_deg": [round(v, 4) for v in tk[0, j].tolist()]}
        out.append({"rank": i + 1, "score": float(s[i]), "frequency_hz": f, "period_s": 1.0 / f,
                    "alpha_rad": {leg: float(gaits.alpha_rad[i, j]) for j, leg in enumerate(LEG_NAMES)},
                    "joints": joint_functions(gaits, i), "cycle": table})
    return {
        "schema": CONTROLLER_SCHEMA, "task": spec.task, "model": model, "gait_space": gait_space,
        "equation": "angle_deg(t) = offset_deg + amplitude_deg * sin(2*pi*frequency_hz*t + phase_rad)",
        "joints": {"hfe": "hip flexion-extension theta_h: thigh angle from the forward axis, counter-clockwise "
                          "seen from the leg's outer side (-90 deg hangs down)",
                   "kfe": "knee theta_k: crank angle relative to the thigh (80 deg nearly straight, -80 folded)"},
        "conventions": "docs/conventions.md (workbench leg frame); t = 0 is the start of the gait",
        "legs": list(LEG_NAMES),
        "haa_deg": {leg: float(a) for leg, a in zip(LEG_NAMES, haa_deg, strict=True)},
        "gaits": out,
    }


def best_table(spec: TaskSpec, gaits: GaitBatch, f: np.ndarray, s: np.ndarray) -> list[dict]:
    """One flat row per retained gait (rank, parameters, objectives, score): the best-8 table."""
    rows = []
    for i, p in enumerate(gaits.to_params()):
        row = {"rank": i + 1}
        for name in ("theta_h_min_deg", "theta_k_max_deg"):
            if isinstance(p[name], list):  # per-leg values (a gait-space extension): one column per leg
                row.update({f"{name[:-4]}_{leg.lower()}_deg": v for leg, v in zip(LEG_NAMES, p[name], strict=True)})
            else:
                row[name] = p[name]
        row["frequency_hz"] = p["frequency_hz"]
        row.update({f"alpha_{leg.lower()}_rad": a for leg, a in zip(LEG_NAMES, p["alpha_rad"], strict=True)})
        row.update({"f1": float(f[i, 0]), "f2": float(f[i, 1]), "f3": float(f[i, 2]), "score": float(s[i])})
        rows.append(row)
    return rows
