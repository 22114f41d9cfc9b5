"""The loop at trajectory level: the full-body simulator against tracked open-water trials.

Each scored trial (``score-trials``: ``trajectories/<trial_id>.parquet`` in the trial frame,
``scores.csv`` naming model and solution) is swum again in the simulator
(:func:`workbench.hydro.simulator.simulate`) with its gait from ``<task>-<model>.json`` and a
leg model (the EF, an augmented model from the tunnel diagnosis, the FED-LSTM). Only converged
swims are used; an unconverged one is flagged and left out. A track is cut where the robot comes
within ``wall_margin_m`` of the tank's wall (the simulator has no walls). This module takes data
(the scores' rows and trajectory frames, the gait files' documents) and returns numbers and PNG
bytes; ``workbench.commands.diagnose_trajectory`` reads the files and the ``diagnose`` command
writes the outputs.

Two questions (docs/diagnose-trajectory.md):

1. **How far off is the model?** RMS position (m) and heading (deg) error of the simulated swims
   against the tracked ones (:func:`trajectory_errors`), model by model.
2. **Does the water or the robot add something the model cannot?** Candidate trajectory effects:

   ``current``    a uniform water current (``cx_mps``, ``cy_mps``, tank frame). The robot drifts
                  with the water: its tank velocity is its swimming velocity plus ``c``. The
                  swimming velocity is the base model's body-frame velocity turned by the
                  *tracked* heading, with a free thrust scale and a constant body-frame velocity
                  error per trial (the base model's own misfit); a current is what stays fixed
                  in the tank while the body turns, so it is told apart from any body-frame
                  misfit by the trials' turning (a trial that does not turn carries no evidence).
   ``yaw_drift``  a steady extra yaw rate common to every trial (``rate_dps``; asymmetric
                  buoyancy, an unbalanced leg, a bent keel): the tracked heading minus the
                  base's grows by ``rate t`` in every trial, whatever its gait.

   Each is claimed when it is significant across trials (one-sided t-test at ``alpha``; the
   current's standard error by jackknife over trials) and at least ``min_current_mps`` /
   ``min_yaw_dps``. Without a reference, the base model's own steady yaw misfit is
   indistinguishable from a yaw drift (both are a heading error that grows the same in every
   trial); ``--reference`` (a pool session swum before, same gaits) takes the base from it.
"""

from __future__ import annotations

import io
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
from scipy import stats

from workbench.errors import ContractError, DataError

#: trial model labels (trials.toml) -> gait-file model names
LABELS = {"ef": "ef", "fed-lstm": "lstm", "lstm": "lstm"}


@dataclass
class Track:
    """One tracked trial in its own frame (+Y initial heading, +X right), cut before any wall contact."""

    trial_id: str
    task: str
    model: str
    solution: int
    t_s: np.ndarray
    xy_m: np.ndarray            # (T, 2) trial frame
    heading_rad: np.ndarray     # (T,) change since the start, counter-clockwise
    frame_angle_rad: float      # the trial frame's +Y in the tank, counter-clockwise from tank +X
    cut_at_wall_s: float | None = None   # the track was cut here (robot within wall_margin_m of a wall)

    @property
    def gait_key(self) -> tuple[str, str, int]:
        """(task, gait-file model, solution): the same gait in another session."""
        return self.task, LABELS.get(self.model.lower(), self.model.lower()), self.solution


@dataclass
class SimTrack:
    """The base swim of a trial's gait (trial frame): simulated, or a reference session's track."""

    t_s: np.ndarray
    xy_m: np.ndarray
    yaw_rad: np.ndarray
    #: (T, 2) body-frame velocity (x right, y forward)
    v_body_mps: np.ndarray | None = None
    converged: bool = True
    residual_mps: float = 0.0
    #: (4, T) the legs' flow history of a simulated swim (warm start for another model's swim)
    flow_mps: np.ndarray | None = field(default=None, repr=False)


@dataclass(frozen=True)
class TrajectorySettings:
    """Trajectory-level knobs (``pipelines/diagnose.yaml`` section ``trajectory``)."""

    min_gain: float = 0.1            # kept for old parameter files (the claim rule is below)
    alpha: float = 0.05
    yaw_bounds_dps: tuple[float, float] = (-30.0, 30.0)
    dt_s: float = 1.0 / 65.0
    max_duration_s: float = 60.0
    #: a current or yaw drift smaller than this is not claimed (tracking resolves about 1 mm/s, 0.05 deg/s)
    min_current_mps: float = 0.002
    min_yaw_dps: float = 0.1
    #: tracks end where the robot comes this close to a wall (half the body length plus a margin)
    wall_margin_m: float = 0.25
    #: a trial whose heading turns less than this carries no evidence on a current (the body frame
    #: cannot be told from the tank frame)
    min_turn_deg: float = 20.0
    #: window nets (the FED-LSTM: a seq_len, no fast path of their own) swim through the optimiser's
    #: per-gait cycle tables (gait/tabulate.py; S within 0.3-1.4 % of the direct rollout, docs/gaits.md)
    #: instead of the model on every tick of every leg (about 50 s per 60 s swim on 2 cores)
    tabulate_models: bool = True


# ------------------------------------------------------------------------------------------- input
def _frame_angle(xy_tank: np.ndarray, xy_trial: np.ndarray) -> float:
    """Angle of the trial frame's +Y in the tank (Procrustes fit of tank - origin = R [X, Y])."""
    a = xy_tank - xy_tank[0]
    b = xy_trial - xy_trial[0]
    # tank = X right + Y heading, right = (sin p, -cos p), heading = (cos p, sin p)
    c = (a[:, 0] * b[:, 1] + a[:, 1] * (-b[:, 0])).sum()
    s = (a[:, 1] * b[:, 1] + a[:, 0] * b[:, 0]).sum()
    return float(np.arctan2(s, c))


def track_from_frame(row: dict, tr, tank_m: tuple[float, float] | None = None, wall_margin_m: float = 0.25,
                     where: str | Path | None = None) -> Track:
    """One scored trial as a :class:`Track`: its ``scores.csv`` row and its trajectory frame.

    ``tr``: the trial's ``trajectories/<trial_id>.parquet`` (polars frame). ``tank_m`` (width,
    length): the track is cut at its first sample within ``wall_margin_m`` of a wall, where a pool
    robot is held by the wall and the simulator (which has none) no longer applies. ``where``:
    the file, named in the error for a frame that cannot be used.
    """
    missing = {"time_s", "X_m", "Y_m", "heading_change_deg"} - set(tr.columns)
    if missing:
        raise DataError(f"trajectory lacks column(s) {sorted(missing)}", path=where)
    ok = tr["time_s"].to_numpy() >= 0
    if "detected" in tr.columns:
        seen = tr["detected"].to_numpy().astype(bool)
        if "filled" in tr.columns:
            seen |= tr["filled"].to_numpy().astype(bool)
        ok &= seen
    ok &= np.isfinite(tr["X_m"].to_numpy()) & np.isfinite(tr["heading_change_deg"].to_numpy())
    t = tr["time_s"].to_numpy()[ok]
    xy = tr.select(["X_m", "Y_m"]).to_numpy()[ok]
    tank = tr.select(["x_m", "y_m"]).to_numpy()[ok] if "x_m" in tr.columns else None
    heading = np.radians(tr["heading_change_deg"].to_numpy()[ok])
    cut = None
    if tank is not None and tank_m is not None:
        w, ln = tank_m
        near = ((tank[:, 0] < wall_margin_m) | (tank[:, 0] > w - wall_margin_m)
                | (tank[:, 1] < wall_margin_m) | (tank[:, 1] > ln - wall_margin_m))
        if near.any():
            k = int(np.argmax(near))
            cut = float(t[k]) if k < len(t) else None
            t, xy, tank, heading = t[:k], xy[:k], tank[:k], heading[:k]
    if len(t) < 5:
        raise DataError(f"{len(t)} usable samples" + (" before the robot reached the wall" if cut is not None
                                                      else ""), path=where)
    angle = _frame_angle(tank, xy) if tank is not None else 0.0
    return Track(str(row["trial_id"]), str(row["task"]), str(row["model"]), int(row["solution"]), t, xy,
                 heading, angle, cut)


def gait_file_name(track: Track) -> str:
    """The gait file a trial's gait comes from: ``<task>-<model>.json`` (the pool's labels mapped to file names)."""
    label = track.model.lower()
    m = re.fullmatch(r"fed-lstm-(\d+)", label)  # the pool's label of a window net's gaits: FED-LSTM-16 -> lstm16
    model = f"lstm{m.group(1)}" if m else LABELS.get(label, label)
    return f"{track.task}-{model}.json"


def gait_from_doc(doc, track: Track, where: str | Path | None = None) -> tuple[dict, dict]:
    """The gait parameters (and fixed constants) a trial swam: its solution rank in the gait file ``doc``."""
    sols = doc.get("solutions", []) if isinstance(doc, dict) else []
    for sol in sols:
        if int(sol.get("rank", -1)) == track.solution:
            return sol["params"], doc.get("fixed") or {}
    raise ContractError(f"no solution of rank {track.solution} for trial {track.trial_id}", path=where)


def simulate_tracks(tracks: list[Track], gaits: Sequence[tuple[dict, dict]], leg_model, robot,
                    settings: TrajectorySettings, sim_settings: dict | None = None,
                    warm: list[SimTrack] | None = None, tabulate: Callable | None = None) -> list[SimTrack]:
    """Swim every trial's gait in the simulator (grouped by the gait files' fixed constants).

    ``gaits``: per track, its gait's ``(params, fixed)`` (:func:`gait_from_doc`).
    ``sim_settings``: keyword arguments for :func:`simulate` (the robot file's ``simulation``
    section, without duration and tick). ``warm``: another model's swims of the same trials
    (e.g. the EF's), whose flow histories start the fixed point (the result does not depend on
    it, only the number of iterations). ``tabulate(model, batch, dt_s)``: wraps a window net
    (a ``seq_len``, no flow provider of its own) for the swims when ``settings.tabulate_models``
    (the command hands in the optimiser's cycle tables, :class:`workbench.gait.tabulate.TabulatedLegModel`).
    Each :class:`SimTrack` says whether its swim converged.
    """
    from workbench.hydro.simulator import GaitBatch, simulate

    kw = {k: v for k, v in (sim_settings or {}).items() if k not in ("duration_s", "dt_s")}
    groups: dict[tuple, list[tuple[int, dict]]] = {}
    for i, (_, (params, fixed)) in enumerate(zip(tracks, gaits, strict=True)):
        key = tuple(sorted((k, float(v)) for k, v in fixed.items()
                           if k in ("theta_h_max_deg", "theta_k_min_deg", "phi_rad")))
        groups.setdefault(key, []).append((i, params))
    out: list[SimTrack | None] = [None] * len(tracks)
    for key, todo in groups.items():
        dur = min(settings.max_duration_s, max(tracks[i].t_s[-1] for i, _ in todo)) + 0.5
        batch = GaitBatch.from_params([p for _, p in todo], **dict(key))
        init = None
        n_ticks = int(round(dur / settings.dt_s)) + 1
        if warm is not None and all(warm[i] is not None and warm[i].flow_mps is not None
                                    and warm[i].flow_mps.shape[-1] == n_ticks for i, _ in todo):
            init = np.stack([warm[i].flow_mps for i, _ in todo])
        model = leg_model
        if tabulate is not None and settings.tabulate_models \
                and not callable(getattr(leg_model, "flow_provider", None)) and getattr(leg_model, "seq_len", 0) > 1:
            model = tabulate(leg_model, batch, settings.dt_s)
        traj = simulate(batch, model, robot, duration_s=dur, dt_s=settings.dt_s, initial_flow=init, **kw)
        for j, (i, _) in enumerate(todo):
            out[i] = SimTrack(traj.t_s, np.stack([traj.x_m[j], traj.y_m[j]], axis=1), traj.yaw_rad[j],
                              np.stack([traj.vx_mps[j], traj.vy_mps[j]], axis=1), bool(traj.converged[j]),
                              float(traj.residual_mps[j]), traj.leg_flow_mps[j])
    return out  # type: ignore[return-value]


def reference_tracks(tracks: list[Track], reference: list[Track]) -> list[SimTrack | None]:
    """The base from a reference session: each trial's gait as tracked there (None where it was not swum).

    The body-frame velocity is the reference track's velocity turned back by its heading.
    """
    by_key = {r.gait_key: r for r in reference}
    out: list[SimTrack | None] = []
    for tr in tracks:
        r = by_key.get(tr.gait_key)
        if r is None:
            out.append(None)
            continue
        v = np.gradient(r.xy_m, r.t_s, axis=0)
        out.append(SimTrack(r.t_s, r.xy_m, r.heading_rad, np.einsum("tji,tj->ti", _rot(r.heading_rad), v)))
    return out


# ------------------------------------------------------------------------------------------ effects
def _rot(a: np.ndarray | float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def _cumtrapz(v: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Cumulative trapezoid integral of (T, ...) samples, starting at zero."""
    d = 0.5 * (v[1:] + v[:-1]) * np.diff(t).reshape((-1,) + (1,) * (v.ndim - 1))
    return np.concatenate([np.zeros_like(v[:1]), np.cumsum(d, axis=0)])


def _tank_to_trial(frame_angle_rad: float, c: np.ndarray) -> np.ndarray:
    """A tank-frame vector seen in the trial frame (tank = R_frame [X, Y], R_frame = [[sin p, cos p], [-cos p, sin p]])."""
    p = frame_angle_rad
    return np.array([c[0] * np.sin(p) - c[1] * np.cos(p), c[0] * np.cos(p) + c[1] * np.sin(p)])


def apply_effects(sim: SimTrack, t_s: np.ndarray, frame_angle_rad: float, yaw_rate_rps: float = 0.0,
                  current_mps: tuple[float, float] = (0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """The base path with the trajectory effects, at times ``t_s``: (xy (T, 2) trial frame, heading (T,)).

    Yaw drift turns the base velocity by ``rate t``; a current (tank frame) adds ``c t``, seen in
    the trial frame.
    """
    t = sim.t_s
    xy = sim.xy_m
    if yaw_rate_rps:
        v = np.gradient(xy, t, axis=0)
        v = np.einsum("tij,tj->ti", _rot(yaw_rate_rps * t), v)
        xy = xy[:1] + _cumtrapz(v, t)
    out = np.stack([np.interp(t_s, t, xy[:, 0]), np.interp(t_s, t, xy[:, 1])], axis=1)
    c = np.asarray(current_mps, float)
    if np.any(c):
        out = out + np.outer(t_s, _tank_to_trial(frame_angle_rad, c))
    heading = np.interp(t_s, t, sim.yaw_rad) + yaw_rate_rps * t_s
    return out, heading


def _common(track: Track, sim: SimTrack) -> np.ndarray:
    """Mask of the tracked samples the base covers."""
    return track.t_s <= sim.t_s[-1] + 1e-9


def _current_blocks(track: Track, sim: SimTrack) -> tuple[np.ndarray, np.ndarray, float]:
    """One trial's normal-equation block for the current, its body-frame nuisance projected out.

    Model (trial frame): p(t) - p(0) = a int R(psi) u_base + int R(psi) b + c_trial t, psi the
    tracked heading, u_base the base's body velocity, (a, b) the trial's nuisance. Returns
    (A (2, 2), y (2,), the heading's turn in degrees).
    """
    m = _common(track, sim)
    t, psi, p = track.t_s[m], track.heading_rad[m], track.xy_m[m]
    u = np.stack([np.interp(t, sim.t_s, sim.v_body_mps[:, k]) for k in range(2)], axis=1)
    rot = _rot(psi)
    cols = [_cumtrapz(np.einsum("tij,tj->ti", rot, u), t),
            _cumtrapz(rot[:, :, 0], t), _cumtrapz(rot[:, :, 1], t)]
    n = np.stack([c.reshape(-1) for c in cols], axis=1)                  # (2T, 3) nuisance
    tt = t - t[0]
    p = p - p[0]
    cx = np.stack([tt * np.sin(track.frame_angle_rad), tt * np.cos(track.frame_angle_rad)], 1).reshape(-1)
    cy = np.stack([-tt * np.cos(track.frame_angle_rad), tt * np.sin(track.frame_angle_rad)], 1).reshape(-1)
    x = np.stack([cx, cy], axis=1)                                       # (2T, 2) current, tank x and y
    y = p.reshape(-1)
    q, _ = np.linalg.qr(n)
    xr = x - q @ (q.T @ x)
    yr = y - q @ (q.T @ y)
    turn = float(np.degrees(np.ptp(psi)))
    return xr.T @ xr, xr.T @ yr, turn


def _yaw_rate(track: Track, sim: SimTrack) -> tuple[float, float]:
    """The trial's steady heading error rate (rad/s, slope of tracked minus base heading) and its duration."""
    m = _common(track, sim)
    t = track.t_s[m]
    e = track.heading_rad[m] - np.interp(t, sim.t_s, sim.yaw_rad)
    return float(np.polyfit(t, e, 1)[0]), float(t[-1] - t[0])


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
    rms_heading_before_deg: dict[str, float] = field(default_factory=dict)
    rms_heading_after_deg: dict[str, float] = field(default_factory=dict)
    tests: dict = field(default_factory=dict)
    excluded: list[dict] = field(default_factory=list)
    base: str = "simulator"

    def to_json(self) -> dict:
        """trajectory_diagnosis.json."""
        def mean(d):
            return float(np.sqrt(np.mean(np.square(list(d.values()))))) if d else None

        return {"model": self.model, "base": self.base, "effects": self.effects, "unexplained": self.unexplained,
                "rms_position_error_m": {"before": mean(self.rms_before_m), "after": mean(self.rms_after_m)},
                "rms_heading_error_deg": {"before": mean(self.rms_heading_before_deg),
                                          "after": mean(self.rms_heading_after_deg)},
                "tests": self.tests, "excluded": self.excluded,
                "per_trial": {k: {"rms_before_m": self.rms_before_m[k], "rms_after_m": self.rms_after_m[k],
                                  "final_before_m": self.final_error_before_m[k],
                                  "final_after_m": self.final_error_after_m[k],
                                  "rms_heading_before_deg": self.rms_heading_before_deg.get(k),
                                  "rms_heading_after_deg": self.rms_heading_after_deg.get(k)}
                              for k in self.rms_before_m}}


def usable(tracks: list[Track], sims: list[SimTrack | None]) -> tuple[list[Track], list[SimTrack], list[dict]]:
    """The trials with a converged base; the others as ``{"trial_id", "reason"}``."""
    keep_t, keep_s, out = [], [], []
    for tr, s in zip(tracks, sims, strict=True):
        if s is None:
            out.append({"trial_id": tr.trial_id, "reason": "its gait was not swum in the reference session"})
        elif not s.converged:
            out.append({"trial_id": tr.trial_id, "reason": f"the simulation did not converge (fixed-point residual "
                        f"{s.residual_mps:.2g} m/s): its path would be an artefact"})
        else:
            keep_t.append(tr)
            keep_s.append(s)
    return keep_t, keep_s, out


def diagnose_trajectories(tracks: list[Track], sims: list[SimTrack | None], model: str = "model",
                          settings: TrajectorySettings | None = None, base: str = "simulator") -> TrajectoryDiagnosis:
    """Which trajectory effects (current, yaw drift) the tracked trials show beyond the base; errors before/after."""
    from workbench.diagnose.loop_threads import one_blas_thread

    with one_blas_thread():
        return _diagnose_trajectories(tracks, sims, model, settings or TrajectorySettings(), base)


def _t_test(estimates: np.ndarray) -> tuple[float, float, float]:
    """Mean, standard error and one-sided p of |mean| > 0 for per-trial estimates."""
    n = len(estimates)
    mu = float(np.mean(estimates))
    se = float(np.std(estimates, ddof=1) / np.sqrt(n)) if n > 1 else np.inf
    t = abs(mu) / se if se > 0 else np.inf
    return mu, se, float(stats.t.sf(t, df=max(n - 1, 1)))


def _diagnose_trajectories(tracks, sims, model, s: TrajectorySettings, base: str) -> TrajectoryDiagnosis:
    tracks, sims, excluded = usable(tracks, sims)
    if len(tracks) < 3:
        raise DataError(f"{len(tracks)} tracked trial(s) with a converged base; the trajectory diagnosis needs at "
                        "least three" + (f" ({len(excluded)} left out: " + "; ".join(
                            f"{e['trial_id']}: {e['reason']}" for e in excluded) + ")" if excluded else ""))
    effects, tests = [], {}
    # --- yaw drift: the heading error's steady rate, common to every trial -----------------------
    rates = np.array([_yaw_rate(tr, sm)[0] for tr, sm in zip(tracks, sims, strict=True)])
    mu, se, p = _t_test(rates)
    tests["yaw_drift"] = {"rate_dps": float(np.degrees(mu)), "se_dps": float(np.degrees(se)), "p": p,
                          "per_trial_dps": {tr.trial_id: float(np.degrees(r)) for tr, r in zip(tracks, rates,
                                                                                                 strict=True)}}
    yaw = 0.0
    unexplained = []
    if p < s.alpha and abs(np.degrees(mu)) >= s.min_yaw_dps:
        q = stats.t.ppf(0.975, len(rates) - 1) * se
        ev = (f"the heading error grows at {np.degrees(mu):+.2f} deg/s (trials: {np.degrees(rates.min()):+.2f} to "
              f"{np.degrees(rates.max()):+.2f}) in every trial, whatever its gait")
        if base == "simulator":
            # the base model's own steady yaw misfit looks the same: reported, not claimed
            unexplained.append({"kind": "heading_drift", "channels": ["heading_change_deg"],
                                "rate_dps": float(np.degrees(mu)),
                                "ci95_dps": [float(np.degrees(mu - q)), float(np.degrees(mu + q))], "p": p,
                                "evidence": ev + ": a yaw bias of the robot or of the water, or the leg model's own "
                                "yaw misfit, which the trials cannot tell apart; diagnose against a reference session "
                                "(--reference) to name it."})
        else:
            yaw = mu
            effects.append({"name": "yaw_drift", "params": {"rate_dps": float(np.degrees(mu))},
                            "ci95": {"rate_dps": [float(np.degrees(mu - q)), float(np.degrees(mu + q))]},
                            "p": p, "evidence": ev + f", beyond the reference session {base!r}."})
    # --- current: fixed in the tank while the body turns -----------------------------------------
    blocks = [_current_blocks(tr, sm) for tr, sm in zip(tracks, sims, strict=True)]
    turning = [i for i, b in enumerate(blocks) if b[2] >= s.min_turn_deg]
    current = np.zeros(2)
    tests["current"] = {"turning_trials": [tracks[i].trial_id for i in turning]}
    if len(turning) >= 3:
        a = sum(blocks[i][0] for i in turning)
        b = sum(blocks[i][1] for i in turning)
        if np.linalg.cond(a) < 1e8:
            c = np.linalg.solve(a, b)
            jack = np.array([np.linalg.lstsq(a - blocks[i][0], b - blocks[i][1], rcond=None)[0] for i in turning])
            n = len(turning)
            mag = float(np.hypot(*c))
            direction = c / mag if mag > 0 else np.array([1.0, 0.0])
            proj = jack @ direction
            se_c = float(np.sqrt((n - 1) / n * np.sum((proj - proj.mean()) ** 2)))
            t = mag / se_c if se_c > 0 else np.inf
            pc = float(stats.t.sf(t, df=n - 1))
            cov = (n - 1) / n * (jack - jack.mean(0)).T @ (jack - jack.mean(0))
            half = stats.t.ppf(0.975, n - 1) * np.sqrt(np.diag(cov))
            tests["current"].update({"cx_mps": float(c[0]), "cy_mps": float(c[1]), "speed_mps": mag,
                                     "se_mps": se_c, "p": pc})
            if pc < s.alpha and mag >= s.min_current_mps:
                current = c
                effects.append({"name": "current", "params": {"cx_mps": float(c[0]), "cy_mps": float(c[1])},
                                "ci95": {"cx_mps": [float(c[0] - half[0]), float(c[0] + half[0])],
                                         "cy_mps": [float(c[1] - half[1]), float(c[1] + half[1])]},
                                "p": pc, "evidence": f"a drift of {100 * mag:.2f} cm/s fixed in the tank while "
                                f"the robot turns ({n} turning trials; each trial's thrust and body-frame "
                                "velocity error fitted beside it)"})
        else:
            tests["current"]["note"] = "the turning trials' headings do not separate tank from body frame"
    else:
        tests["current"]["note"] = (f"{len(turning)} trial(s) turn by {s.min_turn_deg:g} deg or more; a current "
                                    "needs at least three (it is told from the body-frame misfit by turning)")
    final = {"yaw_rate_rps": float(yaw), "current_mps": (float(current[0]), float(current[1]))}
    none = {"yaw_rate_rps": 0.0, "current_mps": (0.0, 0.0)}
    rb, ra, fb, fa, hb, ha = {}, {}, {}, {}, {}, {}
    for tr, sim in zip(tracks, sims, strict=True):
        m = _common(tr, sim)
        for p_, rms, fin, hd in ((none, rb, fb, hb), (final, ra, fa, ha)):
            xy, h = apply_effects(sim, tr.t_s[m], tr.frame_angle_rad, p_["yaw_rate_rps"], p_["current_mps"])
            e = np.linalg.norm(tr.xy_m[m] - xy, axis=1)
            rms[tr.trial_id] = float(np.sqrt(np.mean(e ** 2)))
            fin[tr.trial_id] = float(e[-1])
            hd[tr.trial_id] = float(np.degrees(np.sqrt(np.mean((tr.heading_rad[m] - h) ** 2))))
    left = np.sqrt(np.mean(np.square(list(ra.values()))))
    if left > 0.1:
        unexplained.append({"kind": "trajectory_misfit", "channels": ["X_m", "Y_m"],
                            "evidence": f"{left:.2f} m RMS position error remains after the trajectory effects: "
                            "the leg model's thrust or the body model is off (diagnose the leg model in the tunnel)."})
    return TrajectoryDiagnosis(model, effects, rb, ra, fb, fa, unexplained, final, hb, ha, tests, excluded, base)


# ------------------------------------------------------------------------------ models side by side
def trajectory_errors(tracks: list[Track], sims: list[SimTrack | None]) -> dict:
    """RMS position (m) and heading (deg) error of a model's swims against the tracked trials.

    Per trial over its tracked samples (cut at the wall); overall the root mean square over trials
    of the per-trial RMS, and the mean final position error. Unconverged swims are listed, not used.
    """
    keep_t, keep_s, excluded = usable(tracks, sims)
    per = {}
    for tr, sim in zip(keep_t, keep_s, strict=True):
        m = _common(tr, sim)
        xy, h = apply_effects(sim, tr.t_s[m], tr.frame_angle_rad)
        e = np.linalg.norm(tr.xy_m[m] - xy, axis=1)
        per[tr.trial_id] = {"rms_position_m": float(np.sqrt(np.mean(e ** 2))), "final_position_m": float(e[-1]),
                            "rms_heading_deg": float(np.degrees(np.sqrt(np.mean((tr.heading_rad[m] - h) ** 2)))),
                            "duration_s": float(tr.t_s[m][-1]), "task": tr.task, "gait_model": tr.model}
    def rms(key):
        return float(np.sqrt(np.mean([v[key] ** 2 for v in per.values()]))) if per else None

    return {"rms_position_m": rms("rms_position_m"), "rms_heading_deg": rms("rms_heading_deg"),
            "mean_final_position_m": float(np.mean([v["final_position_m"] for v in per.values()])) if per else None,
            "n_trials": len(per), "excluded": excluded, "per_trial": per}


ERRORS_HEADER = ["model", "trials", "RMS position (m)", "RMS heading (deg)", "mean final position (m)",
                 "effects named", "reported"]


def errors_rows(doc: dict) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of "Trajectory error: models side by side" from a ``trajectory_errors.json`` document."""
    def f(v, fmt):
        return "-" if not isinstance(v, (int, float)) else format(v, fmt)

    rows = []
    for label, m in (doc.get("models") or {}).items():
        eff = ", ".join(f"{e['name']} ({', '.join(f'{k} {v:+.3g}' for k, v in e['params'].items())})"
                        for e in m.get("effects", [])) or "none"
        rep = ", ".join(u["kind"] + (f" {u['rate_dps']:+.2f} deg/s" if isinstance(u.get("rate_dps"), float) else "")
                        for u in m.get("unexplained", [])) or "-"
        n = f"{m.get('n_trials', 0)}" + (f" ({len(m['excluded'])} unconverged, left out)" if m.get("excluded") else "")
        rows.append([label, n, f(m.get("rms_position_m"), ".3f"), f(m.get("rms_heading_deg"), ".1f"),
                     f(m.get("mean_final_position_m"), ".3f"), eff, rep])
    return list(ERRORS_HEADER), rows


def errors_table(doc: dict) -> str:
    """Markdown table "Trajectory error: models side by side" from a ``trajectory_errors.json`` document."""
    header, rows = errors_rows(doc)
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def fig_errors(tracks: list[Track], runs: dict[str, list[SimTrack | None]], errors: dict) -> bytes:
    """PNG bytes: every trial in its frame, tracked and each model's swim; beside them the RMS errors per model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(tracks)
    cols = min(n, 4)
    rows = int(np.ceil(n / cols)) + 1
    fig, axes = plt.subplots(rows, cols, figsize=(3.4 * cols, 3.2 * rows), squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, (ax, tr) in enumerate(zip(axes[1:].ravel(), tracks, strict=False)):
        ax.plot(tr.xy_m[:, 0], tr.xy_m[:, 1], color="0.1", lw=1.8, label="tracked")
        for j, (label, sims) in enumerate(runs.items()):
            s = sims[k]
            if s is None or not s.converged:
                continue
            m = _common(tr, s)
            xy, _ = apply_effects(s, tr.t_s[m], tr.frame_angle_rad)
            ax.plot(xy[:, 0], xy[:, 1], color=colours[j % len(colours)], lw=1, label=label)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"{tr.trial_id}" + (" (cut at wall)" if tr.cut_at_wall_s is not None else ""), fontsize=8)
        ax.set_xlabel("X (m)", fontsize=7)
        ax.tick_params(labelsize=6)
    for ax in axes[1:].ravel()[n:]:
        ax.axis("off")
    if n:
        axes[1, 0].legend(fontsize=6)
    labels = list(errors)
    for ax, key, unit in ((axes[0, 0], "rms_position_m", "RMS position error (m)"),
                          (axes[0, min(1, cols - 1)], "rms_heading_deg", "RMS heading error (deg)")):
        vals = [errors[m].get(key) or 0.0 for m in labels]
        ax.bar(range(len(labels)), vals, color=[colours[j % len(colours)] for j in range(len(labels))])
        ax.set_xticks(range(len(labels)), labels, fontsize=7, rotation=15)
        ax.set_ylabel(unit, fontsize=8)
        for j, v in enumerate(vals):
            ax.text(j, v, f"{v:.2f}", ha="center", va="bottom", fontsize=7)
    for ax in axes[0, 2:]:
        ax.axis("off")
    fig.suptitle("Tracked pool trials against the simulator with each leg model (trial frames)")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()
