"""Runs a diagnosis asks for: separate effects the held-out data could not tell apart.

``diagnosis.json`` (contract section 4) may mark an effect ``"ambiguous_with": [names]``. Two
effects are told apart by a run in which one of them vanishes or changes differently:

* one depends on the flow (circulatory lag, drag, lift, the normal-force law) and the other does
  not (inertia, added mass, servo lag, weight and buoyancy, load-cell cross-talk): **zero-flow
  runs**, in which the flow-borne effect vanishes, at the lowest and highest frequency, plus one at
  the highest flow speed where it is largest;
* both of the same kind: a **frequency pair** at the middle flow speed (lowest and highest
  frequency): a lag's share grows with the rate, a static or inertial error's does not in the same way.

Each run is at the median stroke of the operating region (so it also counts for the region).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from workbench.errors import ContractError
from workbench.plan.acquisition import Candidate, RigRanges

#: effect-name fragments of effects that scale with the flow (vanish at zero flow)
FLOW_BORNE = ("wagner", "circulatory", "drag", "lift", "normal_force", "lateral_force", "flow")


def flow_borne(name: str) -> bool:
    """Whether an effect of this name depends on the flow speed (by the effect library's names)."""
    return any(f in name for f in FLOW_BORNE)


def check_diagnosis(doc, path: str | Path | None = None) -> dict:
    """``doc`` if it is a diagnosis (contract section 4: an ``effects`` list), else a ContractError naming ``path``."""
    if not isinstance(doc, dict) or not isinstance(doc.get("effects"), list):
        raise ContractError("diagnosis.json has no 'effects' list (contract section 4)", path=path)
    return doc


def ambiguous_pairs(doc: dict) -> list[tuple[str, str]]:
    """Unordered pairs of effects the diagnosis calls ambiguous, in order of appearance."""
    pairs: list[tuple[str, str]] = []
    for e in doc["effects"]:
        for other in e.get("ambiguous_with") or []:
            pair = tuple(sorted((str(e["name"]), str(other))))
            if pair not in pairs:
                pairs.append(pair)
    return pairs


def diagnosis_runs(doc: dict, ranges: RigRanges, stroke: dict[str, float]) -> list[Candidate]:
    """The runs that would separate each ambiguous pair (module docstring), deduplicated."""
    f_lo, f_hi = ranges.frequency_hz
    speeds = sorted(ranges.flow_speeds_mps)
    u_mid = speeds[len(speeds) // 2]
    out: list[Candidate] = []
    seen: set[tuple] = set()
    for a, b in ambiguous_pairs(doc):
        mixed = flow_borne(a) != flow_borne(b)
        if mixed:
            borne, still = (a, b) if flow_borne(a) else (b, a)
            why = (f"diagnosis: {a} and {b} are ambiguous; at zero flow {borne} (flow-borne) vanishes and "
                   f"{still} stays")
            wanted = [(0.0, f_lo, why), (0.0, f_hi, why),
                      (speeds[-1], f_hi, f"diagnosis: {a} vs {b}: {borne} is largest at the highest flow")]
        else:
            why = f"diagnosis: {a} and {b} are ambiguous; their shares change differently with the rate"
            wanted = [(u_mid, f_lo, why), (u_mid, f_hi, why)]
        for u, f, reason in wanted:
            params = ranges.params(stroke["theta_h_min_deg"], stroke["theta_k_max_deg"], f, stroke["phi_rad"])
            key = (u, tuple(sorted(params.items())))
            if key in seen:
                continue
            seen.add(key)
            out.append(Candidate(params, float(u), ranges.cycles, reason="diagnosis", notes=(reason,)))
    return out


def region_stroke(gait_params: list[dict], ranges: RigRanges) -> dict[str, float]:
    """Median joint range of the retained gaits, clipped into the rig's ranges (phi: the gaits' own)."""
    def med(key):
        vals = [np.mean(p[key]) if isinstance(p[key], list) else p[key] for p in gait_params]
        return float(np.median(vals))

    from workbench.hydro.simulator import PHI_RAD

    return {"theta_h_min_deg": float(np.clip(med("theta_h_min_deg"), *ranges.theta_h_min_deg)),
            "theta_k_max_deg": float(np.clip(med("theta_k_max_deg"), *ranges.theta_k_max_deg)),
            "phi_rad": float(np.clip(PHI_RAD, *ranges.phi_rad))}
