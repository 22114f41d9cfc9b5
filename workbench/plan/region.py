"""The operating region: the states the retained gaits put the legs in, from the full-body simulator.

Each retained gait (``datasets/gaits/<task>-<model>.json``, contract section 5) is swum from rest
by the full-body simulator (EF legs by default: cheap, and the flow a leg sees depends on the
model only mildly); the last ``cycles`` cycles of each leg are the region. A region point is one
tick of one leg: the flow speed that leg saw, its joint angles and rates, *with its history*
(the leg's whole motion is kept, so a window model sees what it would see in the swim).

:class:`Region` holds the legs' motions (one row per gait and leg), the ticks that count and
their weights (every gait weighs the same; within a gait, its legs and ticks alike).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from workbench.errors import ContractError

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
                **{k: [float(s[:, i].min()), float(s[:, i].max())] for i, k in enumerate(STATE)}}


def read_gaits(paths: Sequence[str | Path], max_rank: int | None = None) -> tuple[list[dict], list[str]]:
    """Retained gaits of the gait files (contract section 5): their ``params`` and labels."""
    params, labels = [], []
    for p in map(Path, paths):
        try:
            doc = json.loads(p.read_text(encoding="utf-8"))
            sols = doc["solutions"]
        except FileNotFoundError:
            raise ContractError("gait file not found", path=p) from None
        except (json.JSONDecodeError, KeyError, TypeError) as exc:
            raise ContractError(f"not a gait file ({type(exc).__name__}: {exc}); expected "
                                "{'solutions': [{'rank', 'params'}, ...]}", path=p) from None
        for s in sols:
            if max_rank is not None and int(s.get("rank", 0)) > max_rank:
                continue
            if not isinstance(s, dict) or "params" not in s:
                raise ContractError("a solution without params", path=p)
            params.append(s["params"])
            labels.append(f"{p.stem}#{s.get('rank', len(labels) + 1)}")
    if not params:
        raise ContractError("no retained gaits in the gait files", path=", ".join(map(str, paths)))
    return params, labels


def operating_region(gait_files: Sequence[str | Path], *, robot_yaml: str | Path = "pipelines/robot.yaml",
                     drag_json: str | Path | None = None, duration_s: float = 12.0, cycles: float = 1.0,
                     points_per_cycle: int = 16, max_rank: int | None = None, leg_model=None) -> Region:
    """Swim every retained gait (full-body simulator) and keep each leg's last ``cycles`` cycles.

    ``leg_model``: the legs' force model in the swim (default: the EF). An unconverged swim is an
    error (its states would be made up).
    """
    from workbench.hydro.ef import EmpiricalFormula
    from workbench.hydro.motion import LegMotion
    from workbench.hydro.robot import LEG_NAMES, load_robot
    from workbench.hydro.simulator import DEFAULT_DT_S, GaitBatch, simulate

    params, labels = read_gaits(gait_files, max_rank)
    gaits = GaitBatch.from_params(params)
    robot = load_robot(robot_yaml, drag_json=drag_json)
    traj = simulate(gaits, leg_model or EmpiricalFormula(), robot, duration_s=duration_s, dt_s=DEFAULT_DT_S)
    if not np.all(traj.converged):
        bad = [labels[i] for i in np.flatnonzero(~traj.converged)]
        raise ContractError(f"the swim of {len(bad)} gait(s) did not converge ({', '.join(bad[:3])})",
                            hint="lengthen nothing: check the gait files; the region needs converged swims")
    t = traj.t_s
    legs = gaits.leg_motion(t)
    flow = traj.leg_flow_mps.reshape(4 * len(gaits), len(t))
    motion = LegMotion(legs.dt_s, legs.theta_h_deg, legs.theta_k_deg, legs.omega_h_dps, legs.omega_k_dps, flow,
                       legs.alpha_h_dps2, legs.alpha_k_dps2)
    n = max(2, int(round(points_per_cycle * cycles)))
    ticks, weights = [], []
    for b in range(len(gaits)):
        span = cycles / float(gaits.frequency_hz[b])
        first = max(0, len(t) - 1 - int(round(span / legs.dt_s)))
        idx = np.linspace(first, len(t) - 1, n).round().astype(int)
        for _ in range(4):
            ticks.append(idx)
            weights.append(np.full(n, 1.0 / (4 * n * len(gaits))))
    row_labels = tuple(f"{lab} {leg}" for lab in labels for leg in LEG_NAMES)
    return Region(motion, np.array(ticks), np.array(weights), row_labels, tuple(str(p) for p in gait_files))
