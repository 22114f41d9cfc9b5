"""The operating region: the states the retained gaits put the legs in, from the full-body simulator.

Each retained gait (``datasets/gaits/<task>-<model>.json``, contract section 5; the command reads
the files and hands their documents in) is swum from rest by the full-body simulator; the last ``cycles`` cycles of each leg are the region. A region point
is one tick of one leg: the flow speed that leg saw, its joint angles and rates, *with its history*
(the leg's whole motion is kept, so a window model sees what it would see in the swim).

Which legs swim a file's gaits: ``legs(path, doc, gaits)`` (a callable the caller hands in) returns
the leg force model and a note, e.g. the model the gaits were optimised with, tabulated as the
optimiser does (``workbench.commands.plan_campaign.own_legs``; this package may not import
``gait``); ``None`` (or no ``legs``) swims EF legs. The notes are kept in :attr:`Region.leg_models`.

:class:`Region` holds the legs' motions (one row per gait and leg), the ticks that count and
their weights (every gait weighs the same; within a gait, its legs and ticks alike).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from workbench.errors import ContractError, ConvergenceError

#: the state of a region point, in FEATURES order
STATE = ("flow_speed_mps", "theta_h_deg", "theta_k_deg", "omega_h_dps", "omega_k_dps")


@dataclass(frozen=True)
class Region:
    """Legs' motions under the gaits, the region ticks and their weights."""

    #: LegMotion (R legs, T ticks) with the flow each leg saw
    motion: object
    #: (R, n) tick indices of each row that belong to the region (the last cycles, subsampled)
    ticks: np.ndarray
    #: (R, n) weights, summing to 1
    weights: np.ndarray
    #: one label per row: "<file>#<rank> <leg>"
    labels: tuple[str, ...]
    #: the gait files read
    sources: tuple[str, ...]
    #: per gait file: the legs its gaits were swum with (and why, where it fell back to EF)
    leg_models: tuple[str, ...] = ()
    #: seconds the swims took
    swim_s: float = 0.0

    def states(self) -> np.ndarray:
        """(R * n, 5) the region points' states (STATE order)."""
        m = self.motion
        arrs = [m.flow_speed_mps, m.theta_h_deg, m.theta_k_deg, m.omega_h_dps, m.omega_k_dps]
        rows = np.repeat(np.arange(self.ticks.shape[0]), self.ticks.shape[1])
        cols = self.ticks.ravel()
        return np.stack([a[rows, cols] for a in arrs], axis=-1)

    def summary(self) -> dict:
        """Ranges of the states (JSON)."""
        s = self.states()
        return {"legs": len(self.labels), "points": int(s.shape[0]), "gait_files": list(self.sources),
                "leg_models": list(self.leg_models), "swim_s": self.swim_s,
                **{k: [float(s[:, i].min()), float(s[:, i].max())] for i, k in enumerate(STATE)}}


#: one gait file: its path (for names and messages), its document, its retained gaits' params and their labels
GaitFile = tuple[Path, dict, list, list]


def gait_files_from_docs(docs: Sequence[tuple[str | Path, Any]], max_rank: int | None = None) -> list[GaitFile]:
    """Per gait file (contract section 5, read by the command): its path, document, retained ``params`` and labels.

    ``docs``: ``(path, parsed JSON)`` per file; the path names the file in labels and errors.
    """
    out, n = [], 0
    for path, doc in docs:
        p = Path(path)
        try:
            sols = doc["solutions"]
            iter(sols)
        except (KeyError, TypeError) as exc:
            raise ContractError(f"not a gait file ({type(exc).__name__}: {exc}); expected "
                                "{'solutions': [{'rank', 'params'}, ...]}", path=p) from None
        params, labels = [], []
        for s in sols:
            if not isinstance(s, dict) or "params" not in s:
                raise ContractError("a solution without params", path=p)
            if max_rank is not None and int(s.get("rank", 0)) > max_rank:
                continue
            params.append(s["params"])
            labels.append(f"{p.stem}#{s.get('rank', n + len(labels) + 1)}")
        n += len(params)
        if params:
            out.append((p, doc, params, labels))
    if not out:
        raise ContractError("no retained gaits in the gait files", path=", ".join(str(p) for p, _ in docs))
    return out


def retained_params(files: Sequence[GaitFile]) -> list[dict]:
    """The retained gaits' ``params`` of all the gait files, in order."""
    return [x for f in files for x in f[2]]


#: the gait file's fixed values a swim must use (the rest of the gait is in each solution's params)
_FIXED = ("theta_h_max_deg", "theta_k_min_deg", "phi_rad")

LegsFor = Callable[[Path, dict, Any], tuple[Any, str]]


def operating_region(files: Sequence[GaitFile], robot, *, duration_s: float = 12.0, cycles: float = 1.0,
                     points_per_cycle: int = 16, leg_model=None, legs: LegsFor | None = None) -> Region:
    """Swim every retained gait (full-body simulator) and keep each leg's last ``cycles`` cycles.

    ``files``: the gait files (:func:`gait_files_from_docs`); ``robot``: the robot's constants
    (:class:`workbench.hydro.robot.RobotSettings`, the command loads them). Each gait file's gaits
    are swum together, with the legs ``legs(path, doc, gaits)`` returns (a model and a note;
    ``None``: EF), else ``leg_model``, else the EF. An unconverged swim is an error (its states
    would be made up).
    """
    import time

    from workbench.hydro.ef import EmpiricalFormula
    from workbench.hydro.motion import LegMotion
    from workbench.hydro.robot import LEG_NAMES
    from workbench.hydro.simulator import DEFAULT_DT_S, GaitBatch, simulate

    t0 = time.perf_counter()
    freqs, legs_rows, labels, notes = [], [], [], []
    for path, doc, params, labs in files:
        fixed = {k: float(v) for k, v in (doc.get("fixed") or {}).items() if k in _FIXED}
        gaits = GaitBatch.from_params(params, **fixed)
        model, note = (legs(path, doc, gaits) if legs is not None else
                       (leg_model, getattr(leg_model, "name", "given") if leg_model is not None else "ef"))
        notes.append(f"{path.name}: {note}")
        traj = simulate(gaits, model if model is not None else EmpiricalFormula(), robot, duration_s=duration_s,
                        dt_s=DEFAULT_DT_S)
        if not np.all(traj.converged):
            bad = [labs[i] for i in np.flatnonzero(~traj.converged)]
            raise ConvergenceError(f"the swim of {len(bad)} gait(s) with {note} legs did not converge "
                                f"({', '.join(bad[:3])})", path=path,
                                hint="the region needs converged swims; check the gait file and its model")
        t = traj.t_s
        lm = gaits.leg_motion(t)
        flow = traj.leg_flow_mps.reshape(4 * len(gaits), len(t))
        legs_rows.append((lm, flow))
        freqs += [float(f) for f in gaits.frequency_hz]
        labels += labs
    swim_s = time.perf_counter() - t0

    def cat(name):
        arrs = [getattr(lm, name) for lm, _ in legs_rows]
        return None if any(a is None for a in arrs) else np.concatenate(arrs)

    dt = legs_rows[0][0].dt_s
    motion = LegMotion(dt, cat("theta_h_deg"), cat("theta_k_deg"), cat("omega_h_dps"), cat("omega_k_dps"),
                       np.concatenate([f for _, f in legs_rows]), cat("alpha_h_dps2"), cat("alpha_k_dps2"))
    n_t = motion.theta_h_deg.shape[1]
    n = max(2, int(round(points_per_cycle * cycles)))
    ticks, weights = [], []
    for f in freqs:
        span = cycles / f
        first = max(0, n_t - 1 - int(round(span / dt)))
        idx = np.linspace(first, n_t - 1, n).round().astype(int)
        for _ in range(4):
            ticks.append(idx)
            weights.append(np.full(n, 1.0 / (4 * n * len(freqs))))
    row_labels = tuple(f"{lab} {leg}" for lab in labels for leg in LEG_NAMES)
    return Region(motion, np.array(ticks), np.array(weights), row_labels, tuple(str(f[0]) for f in files),
                  tuple(notes), swim_s)
