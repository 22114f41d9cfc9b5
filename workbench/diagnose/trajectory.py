"""The loop at trajectory level: the full-body simulator against tracked open-water trials.

Each scored trial (``score-trials``: ``trajectories/<trial_id>.parquet`` in the trial frame,
``scores.csv`` naming model and solution) is swum again in the simulator
(:func:`workbench.hydro.simulator.simulate`) with its gait from ``<task>-<model>.json`` and
the diagnosed leg model. The residual is the tracked minus the simulated path. Candidate
trajectory effects (documented in docs/diagnose.md):

``current``    a uniform water current (``cx_mps``, ``cy_mps``, tank frame): the robot drifts
               with the water, so its path gains ``c t`` (linear, least squares);
``yaw_drift``  a steady extra yaw rate (``rate_dps``; asymmetric buoyancy, an unbalanced leg, a
               yaw moment): the simulated velocity turns by ``rate t`` (1-D search around the
               linear fit).

Effects are judged by leave-one-trial-out prediction error (trials are few) and claimed when
they cut it by at least ``min_gain`` and a one-sided paired t-test over trials is significant.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import optimize, stats

from workbench.errors import ContractError, DataError

#: trial model labels (trials.toml) -> gait-file model names
LABELS = {"ef": "ef", "fed-lstm": "lstm", "lstm": "lstm"}


@dataclass
class Track:
    """One tracked trial in its own frame (+Y initial heading, +X right)."""

    trial_id: str
    task: str
    model: str
    solution: int
    t_s: np.ndarray
    xy_m: np.ndarray            # (T, 2) trial frame
    heading_rad: np.ndarray     # (T,) change since the start, counter-clockwise
    frame_angle_rad: float      # the trial frame's +Y in the tank, counter-clockwise from tank +X


@dataclass
class SimTrack:
    """The simulated swim of a trial's gait (simulator grid, trial frame)."""

    t_s: np.ndarray
    xy_m: np.ndarray
    yaw_rad: np.ndarray


@dataclass(frozen=True)
class TrajectorySettings:
    """Trajectory-level knobs (``pipelines/diagnose.yaml`` section ``trajectory``)."""

    min_gain: float = 0.1
    alpha: float = 0.05
    yaw_bounds_dps: tuple[float, float] = (-30.0, 30.0)
    dt_s: float = 1.0 / 65.0
    max_duration_s: float = 60.0


def _frame_angle(xy_tank: np.ndarray, xy_trial: np.ndarray) -> float:
    """Angle of the trial frame's +Y in the tank (Procrustes fit of tank - origin = R [X, Y])."""
    a = xy_tank - xy_tank[0]
    b = xy_trial - xy_trial[0]
    # tank = X right + Y heading, right = (sin p, -cos p), heading = (cos p, sin p)
    c = (a[:, 0] * b[:, 1] + a[:, 1] * (-b[:, 0])).sum()
    s = (a[:, 1] * b[:, 1] + a[:, 0] * b[:, 0]).sum()
    return float(np.arctan2(s, c))


def read_tracks(scores_dir: str | Path) -> list[Track]:
    """The scored trials of a ``score-trials`` output folder (scores.csv + trajectories/*.parquet)."""
    import polars as pl

    root = Path(scores_dir)
    csv = root / "scores.csv"
    if not csv.is_file():
        raise ContractError("no scores.csv here", path=root, hint="run `workbench score-trials DIR --out DIR` first")
    scores = pl.read_csv(csv)
    out = []
    for row in scores.iter_rows(named=True):
        path = root / "trajectories" / f"{row['trial_id']}.parquet"
        if not path.is_file():
            raise DataError("trajectory file missing", path=path)
        tr = pl.read_parquet(path)
        ok = tr["time_s"].to_numpy() >= 0
        if "detected" in tr.columns:
            seen = tr["detected"].to_numpy().astype(bool)
            if "filled" in tr.columns:
                seen |= tr["filled"].to_numpy().astype(bool)
            ok &= seen
        t = tr["time_s"].to_numpy()[ok]
        xy = tr.select(["X_m", "Y_m"]).to_numpy()[ok]
        tank = tr.select(["x_m", "y_m"]).to_numpy()[ok] if "x_m" in tr.columns else xy
        if len(t) < 5:
            raise DataError(f"{len(t)} usable samples", path=path)
        out.append(Track(str(row["trial_id"]), str(row["task"]), str(row["model"]), int(row["solution"]), t, xy,
                         np.radians(tr["heading_change_deg"].to_numpy()[ok]), _frame_angle(tank, xy)))
    return out


def gait_for(gaits_dir: str | Path, track: Track) -> tuple[dict, dict]:
    """The gait parameters (and fixed constants) a trial swam: ``<task>-<model>.json``, its solution rank."""
    model = LABELS.get(track.model.lower(), track.model.lower())
    path = Path(gaits_dir) / f"{track.task}-{model}.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ContractError(f"cannot read the gait file ({exc})", path=path) from None
    for sol in doc.get("solutions", []):
        if int(sol.get("rank", -1)) == track.solution:
            return sol["params"], doc.get("fixed") or {}
    raise ContractError(f"no solution of rank {track.solution} for trial {track.trial_id}", path=path)


def simulate_tracks(tracks: list[Track], gaits_dir, leg_model, robot, settings: TrajectorySettings) -> list[SimTrack]:
    """Swim every trial's gait in the simulator (grouped by the gait files' fixed constants)."""
    from workbench.hydro.simulator import GaitBatch, simulate

    groups: dict[tuple, list[tuple[int, dict]]] = {}
    for i, tr in enumerate(tracks):
        params, fixed = gait_for(gaits_dir, tr)
        key = tuple(sorted((k, float(v)) for k, v in fixed.items()
                           if k in ("theta_h_max_deg", "theta_k_min_deg", "phi_rad")))
        groups.setdefault(key, []).append((i, params))
    out: list[SimTrack | None] = [None] * len(tracks)
    for key, todo in groups.items():
        dur = min(settings.max_duration_s, max(tracks[i].t_s[-1] for i, _ in todo)) + 0.5
        batch = GaitBatch.from_params([p for _, p in todo], **dict(key))
        traj = simulate(batch, leg_model, robot, duration_s=dur, dt_s=settings.dt_s)
        for j, (i, _) in enumerate(todo):
            out[i] = SimTrack(traj.t_s, np.stack([traj.x_m[j], traj.y_m[j]], axis=1), traj.yaw_rad[j])
    return out  # type: ignore[return-value]


def _rot(a: np.ndarray | float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def apply_effects(sim: SimTrack, t_s: np.ndarray, frame_angle_rad: float, yaw_rate_rps: float = 0.0,
                  current_mps: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """The simulated path with the trajectory effects, at times ``t_s``: (xy (T, 2) trial frame, heading (T,)).

    Yaw drift turns the simulated velocity by ``rate t``; a current (tank frame) adds ``c t``,
    seen in the trial frame (rotated by the frame's angle in the tank).
    """
    t = sim.t_s
    xy = sim.xy_m
    if yaw_rate_rps:
        v = np.gradient(xy, t, axis=0)
        v = np.einsum("tij,tj->ti", _rot(yaw_rate_rps * t), v)
        xy = np.concatenate([xy[:1], xy[:1] + np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t)[:, None], axis=0)])
    out = np.stack([np.interp(t_s, t, xy[:, 0]), np.interp(t_s, t, xy[:, 1])], axis=1)
    c = np.asarray(current_mps, float)
    if np.any(c):
        # tank = R_frame [X, Y] with R_frame = [[sin p, cos p], [-cos p, sin p]]; invert it
        p = frame_angle_rad
        cx = c[0] * np.sin(p) - c[1] * np.cos(p)
        cy = c[0] * np.cos(p) + c[1] * np.sin(p)
        out = out + np.outer(t_s, [cx, cy])
    heading = np.interp(t_s, t, sim.yaw_rad) + yaw_rate_rps * t_s
    return out, heading


def _current_columns(track: Track) -> np.ndarray:
    """(T, 2, 2): the trial-frame displacement of a unit current along tank x and tank y."""
    p = track.frame_angle_rad
    t = track.t_s
    ux = np.stack([np.sin(p) * t, np.cos(p) * t], axis=1)
    uy = np.stack([-np.cos(p) * t, np.sin(p) * t], axis=1)
    return np.stack([ux, uy], axis=2)


def _fit(tracks, sims, which: list[str], train: list[int], settings: TrajectorySettings) -> dict:
    """Fit the chosen effects on trials ``train``; returns their parameters."""
    def inner(rate):
        if "current" not in which:
            return {"yaw_rate_rps": rate, "current_mps": (0.0, 0.0)}
        a, b = np.zeros((2, 2)), np.zeros(2)
        for i in train:
            xy, _ = apply_effects(sims[i], tracks[i].t_s, tracks[i].frame_angle_rad, rate)
            x = _current_columns(tracks[i]).reshape(-1, 2)
            r = (tracks[i].xy_m - xy).reshape(-1)
            a += x.T @ x
            b += x.T @ r
        c = np.linalg.lstsq(a, b, rcond=None)[0]
        return {"yaw_rate_rps": rate, "current_mps": (float(c[0]), float(c[1]))}

    def sse(p):
        return sum(_err(tracks[i], sims[i], p) for i in train)

    if "yaw_drift" not in which:
        return inner(0.0)
    lo, hi = np.radians(settings.yaw_bounds_dps)
    grid = np.linspace(lo, hi, 25)
    best = grid[int(np.argmin([sse(inner(r)) for r in grid]))]
    step = grid[1] - grid[0]
    res = optimize.minimize_scalar(lambda r: sse(inner(r)), bounds=(best - step, best + step), method="bounded",
                                   options={"xatol": 1e-5})
    return inner(float(res.x))


def _err(track: Track, sim: SimTrack, p: dict) -> float:
    xy, _ = apply_effects(sim, track.t_s, track.frame_angle_rad, p["yaw_rate_rps"], p["current_mps"])
    return float(((track.xy_m - xy) ** 2).sum())


def _cv_errors(tracks, sims, which, settings) -> np.ndarray:
    """Leave-one-trial-out mean squared position error of each trial."""
    n = len(tracks)
    out = np.zeros(n)
    for i in range(n):
        if not which:
            p = {"yaw_rate_rps": 0.0, "current_mps": (0.0, 0.0)}
        else:
            p = _fit(tracks, sims, which, [j for j in range(n) if j != i], settings)
        out[i] = _err(tracks[i], sims[i], p) / len(tracks[i].t_s)
    return out


@dataclass
class TrajectoryDiagnosis:
    """Outcome at trajectory level (JSON through :meth:`to_json`)."""

    model: str
    effects: list[dict]
    rms_before_m: dict[str, float]
    rms_after_m: dict[str, float]
    final_error_before_m: dict[str, float]
    final_error_after_m: dict[str, float]
    unexplained: list[dict] = field(default_factory=list)
    params: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        """trajectory_diagnosis.json."""
        def mean(d):
            return float(np.sqrt(np.mean(np.square(list(d.values()))))) if d else None

        return {"model": self.model, "effects": self.effects, "unexplained": self.unexplained,
                "rms_position_error_m": {"before": mean(self.rms_before_m), "after": mean(self.rms_after_m)},
                "per_trial": {k: {"rms_before_m": self.rms_before_m[k], "rms_after_m": self.rms_after_m[k],
                                  "final_before_m": self.final_error_before_m[k],
                                  "final_after_m": self.final_error_after_m[k]} for k in self.rms_before_m}}


def diagnose_trajectories(tracks: list[Track], sims: list[SimTrack], model: str = "model",
                          settings: TrajectorySettings | None = None) -> TrajectoryDiagnosis:
    """Forward selection of trajectory effects by leave-one-trial-out error."""
    from workbench.diagnose.loop import one_blas_thread

    with one_blas_thread():
        return _diagnose_trajectories(tracks, sims, model, settings)


def _diagnose_trajectories(tracks, sims, model, settings) -> TrajectoryDiagnosis:
    s = settings or TrajectorySettings()
    if len(tracks) < 3:
        raise DataError(f"{len(tracks)} tracked trial(s); the trajectory diagnosis needs at least three")
    chosen: list[str] = []
    cv = _cv_errors(tracks, sims, chosen, s)
    effects = []
    names = ("current", "yaw_drift")
    while True:
        # single effects, and together: a current and a yaw drift can hide each other one at a time
        rest = [c for c in names if c not in chosen]
        subsets = [[c] for c in rest] + ([rest] if len(rest) > 1 else [])
        found = []
        for sub in subsets:
            cv_c = _cv_errors(tracks, sims, chosen + sub, s)
            d = np.log(np.maximum(cv, 1e-300) / np.maximum(cv_c, 1e-300))
            sd = d.std(ddof=1)
            t = d.mean() / (sd / np.sqrt(len(d))) if sd > 0 else (np.inf if d.mean() > 0 else 0.0)
            p = float(stats.t.sf(t, df=len(d) - 1))
            gain = 1 - cv_c.sum() / cv.sum()
            if p < s.alpha and gain >= s.min_gain:
                found.append((sub, gain, p, cv_c))
        if not found:
            break
        top = max(g for _, g, _, _ in found)
        # the smallest set that does nearly as well as the best
        sub, gain, p, cv_c = min((f for f in found if f[1] >= 0.9 * top), key=lambda f: (len(f[0]), -f[1]))
        for c in sub:
            chosen.append(c)
            effects.append({"name": c, "cv_error_reduction": float(gain), "p": p})
        cv = cv_c
    final = _fit(tracks, sims, chosen, list(range(len(tracks))), s)
    for e in effects:
        if e["name"] == "current":
            e["params"] = {"cx_mps": final["current_mps"][0], "cy_mps": final["current_mps"][1]}
            e["evidence"] = (f"the position error grows linearly in time along one tank direction in every trial; a "
                             f"current removes {e['cv_error_reduction']:.0%} of the left-out error.")
        else:
            e["params"] = {"rate_dps": float(np.degrees(final["yaw_rate_rps"]))}
            e["evidence"] = (f"the heading error grows steadily; a yaw drift of {e['params']['rate_dps']:.2f} deg/s "
                             f"removes {e['cv_error_reduction']:.0%} of the left-out error.")
    none = {"yaw_rate_rps": 0.0, "current_mps": (0.0, 0.0)}
    rb, ra, fb, fa = {}, {}, {}, {}
    for tr, sim in zip(tracks, sims, strict=False):
        for p, rms, fin in ((none, rb, fb), (final, ra, fa)):
            xy, _ = apply_effects(sim, tr.t_s, tr.frame_angle_rad, p["yaw_rate_rps"], p["current_mps"])
            e = np.linalg.norm(tr.xy_m - xy, axis=1)
            rms[tr.trial_id] = float(np.sqrt(np.mean(e ** 2)))
            fin[tr.trial_id] = float(e[-1])
    unexplained = []
    left = np.sqrt(np.mean(np.square(list(ra.values()))))
    if left > 0.1:
        unexplained.append({"kind": "trajectory_misfit", "channels": ["X_m", "Y_m"],
                            "evidence": f"{left:.2f} m RMS position error remains after the trajectory effects: "
                            "the leg model's thrust or the body model is off (diagnose the leg model in the tunnel)."})
    return TrajectoryDiagnosis(model, effects, rb, ra, fb, fa, unexplained, final)
