"""The virtual pool's trajectory source: what the robot does in each trial.

A :class:`PoolTrial` is a trajectory in the robot's start frame with its labels. They come from
the full-body simulator (``workbench.hydro.simulator``) run on the virtual lab's ground-truth leg
physics for the retained gaits of each model (:func:`simulated_trials`, reading the gait files of
data contract section 5), or from synthetic paths (:func:`straight_path`, :func:`circle_path`,
:func:`synthetic_trials`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from workbench.errors import ContractError, ConvergenceError, ModelError, SettingError
from workbench.virtual_lab.pool_settings import PoolSettings, model_display_label


@dataclass(frozen=True)
class PoolTrial:
    """One trial to render: a trajectory in the robot's start frame and its labels.

    ``t_s`` counts from the gait's start; ``x_m`` (right), ``y_m`` (forward) and ``yaw_rad``
    (counter-clockwise) are relative to the start pose, as the simulator's Trajectory gives them.
    """

    id: str
    task: str
    model: str
    solution: int
    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    yaw_rad: np.ndarray
    gait_hz: float = 0.5
    #: tank start pose (x, y, heading deg); None: the task's default with jitter
    start: tuple[float, float, float] | None = None
    #: occlusions as (start, duration) in seconds since the gait's start; None: drawn at random
    occlusions: tuple[tuple[float, float], ...] | None = None
    #: False renders the robot without markers (to test the scorer's error)
    markers: bool = True
    #: shorten the video to this many seconds after the gait's start (to test the scorer's error)
    video_until_s: float | None = None


def straight_path(speed_mps: float = 0.1, drift_deg: float = 3.0, wobble_m: float = 0.01, gait_hz: float = 0.5,
                  duration_s: float = 62.0, dt_s: float = 0.02, ramp_s: float = 2.0):
    """A straight swim with a constant heading drift (a slowly curving path) and gait-rate surge.

    Returns ``(t, x, y, yaw)`` in the start frame.
    """
    t = np.arange(0.0, duration_s + dt_s / 2, dt_s)
    ramp = np.clip(t / ramp_s, 0, 1) ** 2
    v = speed_mps * ramp * (1 + 0.3 * np.sin(2 * np.pi * gait_hz * t))
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    # heading drifts by drift_deg per metre travelled (positive: to the left)
    yaw = np.radians(drift_deg) * s
    vx = -np.sin(yaw) * v
    vy = np.cos(yaw) * v
    x = np.concatenate([[0.0], np.cumsum(0.5 * (vx[1:] + vx[:-1]) * np.diff(t))])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (vy[1:] + vy[:-1]) * np.diff(t))])
    x = x + wobble_m * np.sin(2 * np.pi * gait_hz * t) * ramp
    return t, x, y, yaw


def circle_path(radius_m: float = 0.08, period_s: float = 22.0, direction: int = 1, duration_s: float = 62.0,
                dt_s: float = 0.02, ramp_s: float = 2.0, drift_mps: float = 0.0):
    """Turning on the spot around a circle: the body's centre runs a circle of ``radius_m`` while it yaws.

    The robot swims forward along the circle's tangent (heading = path direction), completing one
    turn in about ``period_s`` once up to speed; ``direction`` +1 turns left, -1 right.
    """
    t = np.arange(0.0, duration_s + dt_s / 2, dt_s)
    # angular speed ramps up smoothly from rest
    w = direction * 2 * np.pi / period_s * np.clip(t / ramp_s, 0, 1) ** 2
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))])
    # centre of the circle to the left (turning left) of the start, on the start frame's x axis
    cx = -direction * radius_m
    x = cx + direction * radius_m * np.cos(yaw)
    y = direction * radius_m * np.sin(yaw)
    y = y + drift_mps * t
    return t, x, y, yaw



def synthetic_trials(s: PoolSettings | None = None, seed: int | None = None) -> list[PoolTrial]:
    """A small synthetic set with paper-like speeds and radii.

    Per model ``best`` straight runs and turns; EF's second solution never finishes either task.
    """
    s = s or PoolSettings()
    rng = np.random.default_rng(s.seed if seed is None else seed)
    out = []
    for model in s.models:
        label = model_display_label(model, s.model_labels)
        for rank in range(1, s.best + 1):
            slow = model == "ef" and rank == 2
            t, x, y, yaw = straight_path(speed_mps=0.025 if slow else rng.uniform(0.08, 0.11),
                                         drift_deg=rng.uniform(-6, 6) * (2 if model == "ef" else 1),
                                         gait_hz=0.5)
            out.append(PoolTrial(f"{model}-straight-{rank}", "straight", label, rank, t, x, y, yaw))
            t, x, y, yaw = circle_path(radius_m=rng.uniform(0.05, 0.14), period_s=90 if slow else rng.uniform(20, 35),
                                       direction=1 if rank % 2 else -1)
            out.append(PoolTrial(f"{model}-turn-{rank}", "turn", label, rank, t, x, y, yaw))
    return out



# --- trajectories from gait files through the simulator ----------------------------------------
def read_gait_file(path: Path) -> dict:
    """A gait file (data contract section 5) with its solutions sorted by rank."""
    from workbench.contract.jsonfile import read_json

    doc = read_json(path, "gait file", hint="run `workbench optimize` first")
    sols = doc.get("solutions") if isinstance(doc, dict) else None
    if not isinstance(sols, list) or not sols:
        raise ContractError("no 'solutions' list", path=path)
    for i, sol in enumerate(sols):
        if not isinstance(sol, dict) or not isinstance(sol.get("params"), dict) or not isinstance(sol.get("rank"), int):
            raise ContractError(f"solution #{i + 1} needs an integer 'rank' and a 'params' table", path=path)
    doc["solutions"] = sorted(sols, key=lambda r: r["rank"])
    return doc


def simulated_trials(gaits_dir: str | Path, s: PoolSettings, *, on_progress=None) -> list[PoolTrial]:
    """Simulate the best ``s.best`` retained gaits of each model and task with the full-body simulator.

    The simulator's settings (fixed-point scheme, tolerance, iterations) come from the robot
    file's ``simulation`` section (pipelines/robot.yaml); the duration covers the 60 s cap plus
    ``post_s``. A trajectory whose fixed-point iteration did not converge is refused with a
    one-line ConvergenceError naming the gait file and the solution: it is not a trial's truth.
    """
    try:
        from workbench.hydro.robot import RobotSettings, load_robot
        from workbench.hydro.simulator import GaitBatch, simulate
    except ImportError as exc:
        raise ModelError(f"the full-body simulator is not available ({exc})",
                         hint="use --synthetic to render synthetic trajectories") from None
    from workbench.trials.scoring import CAP_S

    gaits_dir = Path(gaits_dir)
    # gaits that share the fixed constants (theta_h_max, theta_k_min, phi; the file's "fixed") swim together
    groups: dict[tuple, list[tuple[str, str, int, dict, Path]]] = {}
    for model in s.models:
        for task in s.tasks:
            path = gaits_dir / f"{task}-{model}.json"
            doc = read_gait_file(path)
            fixed = doc.get("fixed") if isinstance(doc.get("fixed"), dict) else {}
            key = tuple(sorted((k, float(v)) for k, v in fixed.items()
                               if k in ("theta_h_max_deg", "theta_k_min_deg", "phi_rad")))
            for sol in doc["solutions"][: s.best]:
                groups.setdefault(key, []).append((model, task, int(sol["rank"]), sol["params"], path))
    robot_path = Path(s.robot_params)
    robot = load_robot(robot_path) if robot_path.is_file() else RobotSettings()
    settings = _sim_settings(robot_path)
    leg_model = _physics(s.physics)
    made: dict[tuple[str, str, int], PoolTrial] = {}
    for key, todo in groups.items():
        labels = [f"solution rank {rank} of {task}-{model}" for model, task, rank, _, _ in todo]
        try:
            batch = GaitBatch.from_params([p for *_, p, _ in todo], labels=labels, **dict(key))
        except SettingError as exc:  # a bad value: the gait file and the solution at fault
            at = labels.index(exc.where) if exc.where in labels else None
            raise exc.located(path=todo[at][-1] if at is not None else gaits_dir) from None
        traj = simulate(batch, leg_model, robot, duration_s=CAP_S + s.post_s + 1.0, dt_s=s.sim_dt_s, **settings)
        for i, (model, task, rank, _, path) in enumerate(todo):
            if not traj.converged[i]:
                raise ConvergenceError(
                    f"solution rank {rank}: the swim on '{s.physics}' physics did not converge (fixed-point "
                    f"residual {traj.residual_mps[i]:.2g} m/s, tolerance {settings.get('tol_mps', 1e-4):g}, "
                    f"{traj.iterations} leg-model calls)", path=path,
                    hint="its trajectory would be an artefact; see docs/hydro.md (simulation settings)")
            label = model_display_label(model, s.model_labels)
            made[(model, task, rank)] = PoolTrial(f"{model}-{task}-{rank}", task, label, rank, traj.t_s, traj.x_m[i],
                                                  traj.y_m[i], traj.yaw_rad[i], gait_hz=float(batch.frequency_hz[i]))
    # the order of the gait files (model, task, rank), whatever the grouping
    return [made[k] for k in sorted(made, key=lambda k: (s.models.index(k[0]), s.tasks.index(k[1]), k[2]))]


def _sim_settings(robot_path: Path) -> dict:
    """The robot file's fixed-point settings (scheme, tolerance, iterations), without duration and tick."""
    from workbench.hydro.simulator import simulation_settings
    from workbench.params import read_section

    if not robot_path.is_file():
        return {}
    section, source = read_section(robot_path, "simulation", required=False)
    doc = simulation_settings(section, path=source)
    return {k: v for k, v in doc.items() if k not in ("duration_s", "dt_s")}


def _physics(spec: str):
    if spec == "truth":
        from workbench.virtual_lab.physics import TrueLegModel

        return TrueLegModel()
    from workbench.hydro.legmodel import load_leg_model

    return load_leg_model(spec)

