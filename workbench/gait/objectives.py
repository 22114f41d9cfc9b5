"""The paper's objectives (Table III) as pure functions of a simulated :class:`Trajectory`, and the score S.

All three objectives are minimised; ``t_final`` is when the task is done (linear between the two
ticks around it, so the objectives vary smoothly with the gait), or the time cap if it never is. Frames follow the trial frame of data contract
section 2 (origin at the start, +Y along the initial heading, +X to the right; yaw positive to
the left, counter-clockwise seen from above).

Straight-line motion:
    f1 = -sum_{t_i < t_final} F_total,Y(t_i) dt   minus the impulse of the total force (legs + body)
                                          along world +Y up to t_final (N s; negative is good)
    f2 = |yaw(t_final) - target|          heading error at the end (rad, or deg by setting)
    f3 = t_final                          time to advance ``finish_distance_m`` along +Y, or the cap (s)

Turn:
    f1 = sum_{t_i < t_final} |p(t_{i+1}) - p(t_i)|   path length up to t_final (m)
    f2 = |psi(t_final) - target|          accumulated yaw error, target 360 deg (rad, or deg)
    f3 = t_final                          time until the accumulated yaw reaches the target, or the cap

S = w1 f1 + w2 f2 + w3 f3 (paper: w = 1, 4, 2) ranks solutions, lower is better.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from workbench.errors import SettingError
from workbench.hydro.simulator import Trajectory

TASKS = ("straight", "turn")
TURN_DIRECTIONS = ("either", "left", "right")
ANGLE_UNITS = ("rad", "deg")


@dataclass(frozen=True)
class TaskSpec:
    """One task's constants (``tasks.<task>`` in pipelines/gait.yaml)."""

    task: str
    #: time cap (s): the simulation runs this long; a task not done by then scores the cap
    cap_s: float = 60.0
    #: straight: distance along the initial heading that counts as finished (m)
    finish_distance_m: float = 2.0
    #: target yaw (deg): straight 0 (keep the heading); turn 360 (one full turn)
    target_yaw_deg: float = 0.0
    #: turn: which way counts (either: the accumulated heading change in any direction)
    turn_direction: str = "either"
    #: unit of f2 (it enters S with weight w2, so the unit changes the ranking)
    angle_unit: str = "rad"
    #: S = w1 f1 + w2 f2 + w3 f3
    weights: tuple[float, float, float] = (1.0, 4.0, 2.0)

    def __post_init__(self):
        if self.task not in TASKS:
            raise SettingError(f"task must be one of {TASKS}, got {self.task!r}")
        if self.turn_direction not in TURN_DIRECTIONS:
            raise SettingError(f"turn_direction must be one of {TURN_DIRECTIONS}, got {self.turn_direction!r}")
        if self.angle_unit not in ANGLE_UNITS:
            raise SettingError(f"angle_unit must be one of {ANGLE_UNITS}, got {self.angle_unit!r}")
        if self.cap_s <= 0 or (self.task == "straight" and self.finish_distance_m <= 0):
            raise SettingError("cap_s and finish_distance_m must be positive")
        if self.task == "turn" and self.target_yaw_deg <= 0:
            raise SettingError("a turn's target_yaw_deg must be positive (the amount of turning)")
        if len(self.weights) != 3:
            raise SettingError("weights needs three numbers w1, w2, w3")

    @classmethod
    def from_dict(cls, task: str, doc: Mapping[str, Any] | None, weights=None, *, key: str | None = None,
                  path: str | None = None) -> "TaskSpec":
        """From ``tasks.<task>`` of the parameter file or a gait file's ``settings.task``.

        Built by :func:`workbench.params.build`: unknown keys, wrong types and failed checks are a
        ParamsError naming ``path`` and ``key``; ``weights`` is the default when the section gives none.
        """
        from workbench.params import build

        doc = dict(doc or {})
        if weights is not None:
            doc.setdefault("weights", weights)
        return build(cls, {**doc, "task": task}, key=key or f"optimize.tasks.{task}", path=path)

    @property
    def names(self) -> dict[str, str]:
        """What f1, f2, f3 are, with units (for files and plots)."""
        unit = self.angle_unit
        if self.task == "straight":
            return {"f1": "minus Y impulse (N s)", "f2": f"yaw error ({unit})", "f3": "time to finish (s)"}
        return {"f1": "path length (m)", "f2": f"accumulated yaw error ({unit})", "f3": "time to turn (s)"}


def _crossing(progress: np.ndarray, target: float) -> tuple[np.ndarray, np.ndarray]:
    """Per row: the tick N before which ``progress`` first reaches ``target`` and the fraction of step N.

    The task is done at t_final = t_N + theta dt (theta in (0, 1], linear between ticks, so
    objectives vary smoothly with the gait); a row that never reaches it ends at the last tick
    (N = T - 1, theta = 0).
    """
    done = progress >= target
    reached = done.any(axis=1) & ~done[:, 0]
    last = progress.shape[1] - 1
    hit = np.where(reached, done.argmax(axis=1), last)                 # first tick at/after the target
    n = np.where(reached, hit - 1, last)
    rows = np.arange(progress.shape[0])
    p0, p1 = progress[rows, n], progress[rows, np.minimum(n + 1, last)]
    theta = np.where(reached, (target - p0) / np.where(p1 > p0, p1 - p0, 1.0), 0.0)
    return n, np.clip(theta, 0.0, 1.0)


def _at(values: np.ndarray, n: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """(B, T) values linearly interpolated at tick n + theta."""
    rows = np.arange(values.shape[0])
    v1 = values[rows, np.minimum(n + 1, values.shape[1] - 1)]
    return values[rows, n] * (1 - theta) + v1 * theta


def _cumulative(steps: np.ndarray) -> np.ndarray:
    """(B, T) running sums of (B, T-1) per-step amounts, 0 at tick 0 (the left Riemann sums of Table III)."""
    return np.concatenate([np.zeros((steps.shape[0], 1)), np.cumsum(steps, axis=1)], axis=1)


def _angle(x_rad: np.ndarray, unit: str) -> np.ndarray:
    return np.degrees(x_rad) if unit == "deg" else x_rad


def straight_objectives(traj: Trajectory, spec: TaskSpec) -> np.ndarray:
    """(B, 3) straight-line objectives (see the module docstring)."""
    n, theta = _crossing(traj.y_m, spec.finish_distance_m)
    total = traj.total_wrench
    # body-frame force -> world +Y (the integrator's rotation: Y = sin(yaw) fx + cos(yaw) fy)
    f_y = np.sin(traj.yaw_rad) * total[..., 0] + np.cos(traj.yaw_rad) * total[..., 1]
    dt = np.diff(traj.t_s)
    impulse = _cumulative(f_y[:, :-1] * dt)
    f1 = -_at(impulse, n, theta)
    f2 = np.abs(_angle(_at(traj.yaw_rad, n, theta) - math.radians(spec.target_yaw_deg), spec.angle_unit))
    f3 = traj.t_s[n] + theta * np.append(dt, 0.0)[n]
    return np.column_stack([f1, f2, f3])


def signed_turn(traj: Trajectory, direction: str) -> np.ndarray:
    """Accumulated yaw (rad) counted in the task's direction: left +yaw, right -yaw, either |yaw|."""
    yaw = traj.yaw_rad
    return {"left": yaw, "right": -yaw, "either": np.abs(yaw)}[direction]


def turn_objectives(traj: Trajectory, spec: TaskSpec) -> np.ndarray:
    """(B, 3) turn objectives (see the module docstring)."""
    target = math.radians(spec.target_yaw_deg)
    psi = signed_turn(traj, spec.turn_direction)
    n, theta = _crossing(psi, target)
    path = _cumulative(np.hypot(np.diff(traj.x_m, axis=1), np.diff(traj.y_m, axis=1)))
    f1 = _at(path, n, theta)
    f2 = np.abs(_angle(_at(psi, n, theta) - target, spec.angle_unit))
    f3 = traj.t_s[n] + theta * np.append(np.diff(traj.t_s), 0.0)[n]
    return np.column_stack([f1, f2, f3])


def objectives(traj: Trajectory, spec: TaskSpec) -> np.ndarray:
    """(B, 3) objectives of the spec's task."""
    return straight_objectives(traj, spec) if spec.task == "straight" else turn_objectives(traj, spec)


def score(f: np.ndarray, weights) -> np.ndarray:
    """S = w1 f1 + w2 f2 + w3 f3 per row of an (n, 3) objective matrix."""
    return np.asarray(f, float) @ np.asarray(weights, float)
