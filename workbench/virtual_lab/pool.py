"""The virtual pool: open-water trial videos of known trajectories, written per data contract section 2.

:func:`generate_pool` writes a trials folder (``trials.toml``, ``videos/``, ``truth.json``) for a
list of trials. The work is split by concern:

- :mod:`~workbench.virtual_lab.pool_settings`: :class:`PoolSettings` (the ``pool`` section of
  pipelines/trials.yaml), the marker paints and the models' display names;
- :mod:`~workbench.virtual_lab.pool_trajectories`: the trajectory source (:class:`PoolTrial`, the
  full-body simulator on the retained gaits, synthetic paths);
- :mod:`~workbench.virtual_lab.pool_render`: the renderer (tilted camera, scene, one trial's video);
- :mod:`~workbench.virtual_lab.pool_cli`: ``workbench virtual-lab pool`` (``add_cli(subparsers)``);
- this module: the folder (start poses, occlusions, true scores, manifest and truth), written atomically.

Every folder gets ``truth.json`` (not part of the contract; readers ignore it): the camera,
the true trajectory at every frame, the occlusions, and the true scores computed from the true
trajectory with the contract's definitions, so the scorer can be checked against them.
The public names of the split modules stay importable from here.
"""

from __future__ import annotations

import json
import math
from contextlib import nullcontext
from dataclasses import asdict
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from workbench.contract.toml_text import toml_value
from workbench.errors import ContractError
from workbench.virtual_lab.pool_cli import EXAMPLES, add_cli
from workbench.virtual_lab.pool_render import Scene, TiltedCamera, render_all, render_trial
from workbench.virtual_lab.pool_settings import DEFAULT_LABELS, MARKER_BGR, PoolSettings, model_display_label
from workbench.virtual_lab.pool_trajectories import (
    PoolTrial,
    circle_path,
    read_gait_file,
    simulated_trials,
    straight_path,
    synthetic_trials,
)

__all__ = ["DEFAULT_LABELS", "EXAMPLES", "MARKER_BGR", "PoolSettings", "PoolTrial", "TiltedCamera", "add_cli",
           "circle_path", "generate_pool", "manifest_text", "model_display_label", "read_gait_file", "render_trial",
           "simulated_trials", "straight_path", "synthetic_trials", "true_scores"]


def _tank_trajectory(trial: PoolTrial, start, s: PoolSettings):
    """Start-frame trajectory -> tank frame (x, y, yaw), held at the walls of the tank."""
    x0, y0, h0 = start
    yaw0 = math.radians(h0)
    c, sn = math.cos(yaw0), math.sin(yaw0)
    x = x0 + c * trial.x_m - sn * trial.y_m
    y = y0 + sn * trial.x_m + c * trial.y_m
    r = 0.5 * max(s.body_length_m, s.body_width_m)
    clamped = bool(np.any((x < r) | (x > s.tank_width_m - r) | (y < r) | (y > s.tank_length_m - r)))
    x = np.clip(x, r, s.tank_width_m - r)
    y = np.clip(y, r, s.tank_length_m - r)
    return x, y, yaw0 + np.asarray(trial.yaw_rad, float), clamped


def true_scores(task: str, t_s, x_tank, y_tank, yaw_tank) -> dict:
    """The contract's scores of a true tank-frame trajectory (start at t = 0), as truth.json holds them."""
    from workbench.trials.geometry import trial_frame
    from workbench.trials.scoring import CAP_S, score_trajectory

    t = np.asarray(t_s, float)
    fwd0 = (-math.sin(yaw_tank[0]), math.cos(yaw_tank[0]))
    frame = trial_frame((x_tank[0], y_tank[0]), fwd0)
    xy = frame.to_trial(np.column_stack([x_tank, y_tank]))
    keep = t <= CAP_S + 1e-9
    sc = score_trajectory(task, t[keep], xy[keep, 0], xy[keep, 1], np.asarray(yaw_tank)[keep] - yaw_tank[0],
                          observed_until_s=float(t[-1]))
    return {"time_s": sc.time_s, "mae_x_m": sc.mae_x_m, "radius_m": sc.radius_m, "completed": sc.completed}


def _toml_value(v) -> str:
    """The contract's TOML value (contract/toml_text.py), floats rounded to 4 decimals as trials.toml has them."""
    def rounded(x):
        if isinstance(x, (list, tuple)):
            return [rounded(y) for y in x]
        return round(x, 4) if isinstance(x, float) else x
    return toml_value(rounded(v))


def manifest_text(trials_id: str, s: PoolSettings, reference_px, reference_m, trials: Sequence[dict]) -> str:
    """trials.toml text per data contract section 2."""
    lines = ['schema = "workbench/trials@1"', f"id = {_toml_value(trials_id)}", "",
             "[tank]", f"width_m = {_toml_value(float(s.tank_width_m))}",
             f"length_m = {_toml_value(float(s.tank_length_m))}", "",
             "[camera]",
             f"reference_px = {_toml_value([[round(float(u), 2), round(float(v), 2)] for u, v in reference_px])}",
             f"reference_m = {_toml_value([[float(x), float(y)] for x, y in reference_m])}", "",
             "[robot]", f"head_marker = {_toml_value(s.head_marker)}", f"tail_marker = {_toml_value(s.tail_marker)}"]
    for t in trials:
        lines += ["", "[[trials]]"] + [f"{k} = {_toml_value(v)}" for k, v in t.items()]
    return "\n".join(lines) + "\n"


def _occlusions_for(trial: PoolTrial, decided_s: float, rng, s: PoolSettings, want: bool):
    if trial.occlusions is not None:
        return tuple(trial.occlusions)
    if not want:
        return ()
    dur = float(rng.uniform(*s.occlusion_duration_s))
    lo, hi = 2.0, max(2.5, decided_s - dur - 1.5)
    return ((float(rng.uniform(lo, hi)), dur),)



def generate_pool(out_dir: str | Path, trials: Sequence[PoolTrial] | None = None, *,
                  settings: PoolSettings | None = None, progress: bool = True, workers: int | None = None) -> Path:
    """Write a trials folder (trials.toml, videos/, truth.json) for the given trajectories.

    Without ``trials`` a synthetic set is rendered (see :func:`synthetic_trials`). The folder is
    built beside the target and swapped in at the end, so a failure leaves the old one intact.
    Trials render in ``workers`` processes (default ``settings.workers``); the bytes do not
    depend on it.
    """
    from workbench.atomic import atomic_dir
    from workbench.console import progress as progress_bar

    s = settings or PoolSettings()
    workers = s.workers if workers is None else workers
    out = Path(out_dir)
    trials = list(trials) if trials is not None else synthetic_trials(s)
    if not trials:
        raise ContractError("no trials to render", path=out)
    ids = [t.id for t in trials]
    if len(set(ids)) != len(ids):
        raise ContractError("duplicate trial ids", path=out)
    rng = np.random.default_rng(s.seed)
    cam = TiltedCamera.looking_at(s)
    scene = Scene(s, cam, np.random.default_rng(s.seed + 1))
    corners = [(0.0, 0.0), (s.tank_width_m, 0.0), (s.tank_width_m, s.tank_length_m), (0.0, s.tank_length_m)]
    ref_px = cam.project(np.array(corners))
    n_occ = int(math.ceil(s.occlusion_fraction * len(trials))) if s.occlusion_fraction > 0 else 0
    occluded = set(rng.choice(len(trials), size=min(n_occ, len(trials)), replace=False).tolist()) if n_occ else set()
    jobs, entries, truth_trials = [], [], {}
    for k, tr in enumerate(trials):
        default = s.straight_start if tr.task == "straight" else s.turn_start
        start = tr.start or (default[0] + rng.uniform(-1, 1) * s.start_jitter_m,
                             default[1] + rng.uniform(-1, 1) * s.start_jitter_m,
                             default[2] + rng.uniform(-1, 1) * s.start_jitter_deg)
        x, y, yaw, clamped = _tank_trajectory(tr, start, s)
        sc = true_scores(tr.task, tr.t_s, x, y, yaw)
        length = min(sc["time_s"] + max(s.post_s, 2.0 / s.fps), float(tr.t_s[-1]))
        if tr.video_until_s is not None:
            length = min(length, tr.video_until_s)
        occ = _occlusions_for(tr, sc["time_s"], rng, s, k in occluded)
        video = f"videos/{tr.id}.mp4"
        jobs.append(dict(rel=video, t_s=tr.t_s, x_m=x, y_m=y, yaw_rad=yaw, duration_s=length, gait_hz=tr.gait_hz,
                         occlusions=occ, markers=bool(tr.markers and s.draw_markers), seed=s.seed * 1000 + k))
        entries.append({"id": tr.id, "task": tr.task, "model": tr.model, "solution": int(tr.solution),
                        "video": video, "start_s": float(s.start_s)})
        truth_trials[tr.id] = {
            "task": tr.task, "model": tr.model, "solution": int(tr.solution),
            "start_pose": {"x_m": float(start[0]), "y_m": float(start[1]), "heading_deg": float(start[2])},
            "scores": sc, "clamped_at_wall": clamped, "markers_drawn": bool(tr.markers and s.draw_markers)}
    with atomic_dir(out) as tmp:
        ctx = progress_bar("rendering pool trials", total=len(trials)) if progress else nullcontext()
        with ctx as bar:
            for tid, rec in zip(ids, render_all(tmp, jobs, s, cam, scene, workers), strict=True):
                truth_trials[tid].update({
                    "occlusions_video_s": [[float(a), float(b)] for a, b in rec["occlusions_s"]],
                    "video_s": float(rec["video_time_s"][-1] + 1 / s.fps),
                    "frames": {"video_time_s": np.round(rec["video_time_s"], 6).tolist(),
                               "x_m": np.round(rec["x_m"], 6).tolist(), "y_m": np.round(rec["y_m"], 6).tolist(),
                               "yaw_rad": np.round(rec["yaw_rad"], 6).tolist()}})
                if bar:
                    bar.advance(1, tid)
        (tmp / "trials.toml").write_text(manifest_text(s.trials_id, s, ref_px, corners, entries), encoding="utf-8")
        truth = {"note": "virtual pool ground truth; not part of the data contract",
                 "seed": s.seed, "settings": {k: v for k, v in asdict(s).items() if k != "workers"},
                 "camera": {"h_m2px": cam.h_m2px.tolist(), "k": cam.k.tolist()},
                 "yaw_convention": "counter-clockwise from the robot facing tank +Y; body +y forward",
                 "trials": truth_trials}
        (tmp / "truth.json").write_text(json.dumps(truth) + "\n", encoding="utf-8")
    return out


def _jsonable(d):
    if isinstance(d, Mapping):
        return {k: _jsonable(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_jsonable(v) for v in d]
    return d

