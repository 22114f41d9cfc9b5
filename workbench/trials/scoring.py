"""The contract's trial scores on a trajectory in the trial frame (pure numpy/scipy).

Times are seconds since ``start_s``. Crossings are interpolated linearly between samples, so a
score does not snap to the frame grid. Definitions (data contract section 2):

* straight: ``time_s`` when Y first reaches 2.0 m, else 60 (not completed); ``mae_x_m`` the mean
  |X| at the first crossings of Y = 0, 0.25, ..., 2.0 m reached within that time. The robot is at
  Y = 0 (and X = 0) at the start by definition of the frame, so the Y = 0 station counts |X| = 0.
* turn: ``time_s`` when the accumulated (unwrapped) heading change first reaches 360 degrees in
  either direction, else 60; ``radius_m`` the radius of the circle fitted to the positions up to
  that time by geometric least squares (Kasa's algebraic fit as the start).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workbench.errors import ConvergenceError, DataError

#: Contract constants (section 2); not tuning knobs.
CAP_S = 60.0
STRAIGHT_DISTANCE_M = 2.0
STATION_STEP_M = 0.25
TURN_RAD = 2.0 * np.pi


class UndecidedError(DataError):
    """The trajectory ends before the robot finished and before the cap: the trial has no score."""


@dataclass(frozen=True)
class TrialScore:
    """Scores of one trial; ``mae_x_m`` is None for turns, ``radius_m`` None for straight runs."""

    task: str
    time_s: float
    completed: bool
    mae_x_m: float | None = None
    radius_m: float | None = None
    #: straight: (station Y, crossing time, X there) for each station reached
    stations: tuple[tuple[float, float, float], ...] = ()
    #: turn: fitted circle centre (X, Y) in the trial frame
    circle_center: tuple[float, float] | None = None
    notes: tuple[str, ...] = field(default_factory=tuple)


def first_crossing(t: np.ndarray, v: np.ndarray, level: float) -> tuple[float, int] | None:
    """Time at which ``v`` first reaches ``level`` (linear interpolation) and the sample index after it.

    NaN samples are skipped; the crossing is interpolated between the neighbouring valid ones.
    """
    ok = np.isfinite(v) & np.isfinite(t)
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return None
    vv = v[idx]
    hit = np.flatnonzero(vv >= level)
    if hit.size == 0:
        return None
    k = int(hit[0])
    if k == 0:
        return float(t[idx[0]]), int(idx[0])
    i0, i1 = idx[k - 1], idx[k]
    frac = (level - v[i0]) / (v[i1] - v[i0])
    return float(t[i0] + frac * (t[i1] - t[i0])), int(i1)


def _interp_at(t: np.ndarray, v: np.ndarray, tq: float) -> float:
    ok = np.isfinite(v) & np.isfinite(t)
    return float(np.interp(tq, t[ok], v[ok]))


def _gap_note(t: np.ndarray, v: np.ndarray, tq: float, max_gap_s: float, what: str) -> str | None:
    """A note when the crossing at ``tq`` was interpolated across a gap longer than ``max_gap_s``."""
    ok = np.flatnonzero(np.isfinite(v))
    before = ok[t[ok] <= tq]
    after = ok[t[ok] >= tq]
    if before.size and after.size and t[after[0]] - t[before[-1]] > max_gap_s:
        return f"{what} at {tq:.2f} s falls in a tracking gap of {t[after[0]] - t[before[-1]]:.2f} s"
    return None


def _check_coverage(t: np.ndarray, observed_until_s: float | None, frame_s: float) -> None:
    end = float(np.nanmax(t)) if observed_until_s is None else observed_until_s
    if end < CAP_S - frame_s - 1e-9:
        raise UndecidedError(f"the trajectory ends {end:.2f} s after start_s, before the robot finished and "
                             f"before the {CAP_S:.0f} s cap, so the trial cannot be scored")


def score_straight(t: np.ndarray, x: np.ndarray, y: np.ndarray, *, observed_until_s: float | None = None,
                   frame_s: float = 0.0, max_gap_s: float = np.inf) -> TrialScore:
    """Straight-run scores from trial-frame positions sampled at times ``t`` (s since start)."""
    t, x, y = (np.asarray(a, float) for a in (t, x, y))
    keep = t <= CAP_S + 1e-9
    t, x, y = t[keep], x[keep], y[keep]
    notes = []
    hit = first_crossing(t, y, STRAIGHT_DISTANCE_M)
    if hit is None:
        _check_coverage(t, observed_until_s, frame_s)
        time_s, completed, t_end = CAP_S, False, CAP_S
    else:
        time_s, completed, t_end = hit[0], True, hit[0]
        note = _gap_note(t, y, time_s, max_gap_s, "the 2 m crossing")
        if note:
            notes.append(note)
    stations = []
    n_st = int(round(STRAIGHT_DISTANCE_M / STATION_STEP_M))
    for k in range(n_st + 1):
        level = k * STATION_STEP_M
        c = first_crossing(t, y, level)
        if c is None or c[0] > t_end + 1e-9:
            break
        stations.append((level, c[0], _interp_at(t, x, c[0])))
    mae = float(np.mean([abs(s[2]) for s in stations])) if stations else None
    return TrialScore(task="straight", time_s=float(time_s), completed=completed, mae_x_m=mae,
                      stations=tuple(stations), notes=tuple(notes))


#: a fitted radius this many times the points' extent is no circle: the points lie on a line (the
#: arc's bow over the path, L^2 / 8 r, would be under a thousandth of its length L)
MAX_RADIUS_PER_EXTENT = 1e3


class NoCircleError(ConvergenceError):
    """The fit converged to no circle: the positions lie on a line (a turn trial that swam straight)."""


def fit_circle(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float]:
    """Circle ``(cx, cy, r)`` minimising the geometric distances of the points to it.

    Kasa's algebraic fit (linear least squares on x^2 + y^2 + D x + E y + F = 0) starts a
    Levenberg-Marquardt fit of the geometric residuals ``|p - c| - r`` (scipy least_squares).
    Fewer than 3 distinct positions is a :class:`DataError`; a fit that did not converge, or that
    ends without a circle (a radius that is not finite and positive, or over
    ``MAX_RADIUS_PER_EXTENT`` times the points' extent: points on a line) is a
    :class:`ConvergenceError`. What it produced is no radius.
    """
    from scipy.optimize import least_squares

    ok = np.isfinite(x) & np.isfinite(y)
    x, y = np.asarray(x, float)[ok], np.asarray(y, float)[ok]
    if x.size < 3:
        raise DataError(f"only {x.size} valid positions; a circle needs at least 3")
    distinct = np.unique(np.column_stack([x, y]), axis=0).shape[0]
    if distinct < 3:
        raise DataError(f"only {distinct} distinct positions among {x.size}; a circle needs at least 3")
    # centre the data for conditioning
    mx, my = x.mean(), y.mean()
    u, v = x - mx, y - my
    a = np.column_stack([u, v, np.ones_like(u)])
    sol, *_ = np.linalg.lstsq(a, -(u**2 + v**2), rcond=None)
    c0 = np.array([-sol[0] / 2, -sol[1] / 2])
    r0 = np.sqrt(max(c0 @ c0 - sol[2], 1e-12))

    def resid(p):
        return np.hypot(u - p[0], v - p[1]) - p[2]

    res = least_squares(resid, np.array([c0[0], c0[1], r0]), method="lm", x_scale="jac")
    if not res.success:
        raise ConvergenceError(f"the circle fit to {x.size} positions did not converge ({res.message})")
    cx, cy, r = res.x
    extent = float(np.hypot(u, v).max())
    if not (np.all(np.isfinite(res.x)) and 0 < abs(r) <= MAX_RADIUS_PER_EXTENT * extent):
        raise NoCircleError(f"the circle fit to {x.size} positions found no circle (radius {abs(r):.3g} m for "
                               f"points {extent:.3g} m from their centroid): they lie on a line")
    return float(cx + mx), float(cy + my), float(abs(r))


def score_turn(t: np.ndarray, x: np.ndarray, y: np.ndarray, heading_rad: np.ndarray, *,
               observed_until_s: float | None = None, frame_s: float = 0.0,
               max_gap_s: float = np.inf) -> TrialScore:
    """Turn scores from trial-frame positions and unwrapped heading (rad, any origin) at times ``t``."""
    t, x, y, h = (np.asarray(a, float) for a in (t, x, y, heading_rad))
    keep = t <= CAP_S + 1e-9
    t, x, y, h = t[keep], x[keep], y[keep], h[keep]
    okh = np.flatnonzero(np.isfinite(h))
    if okh.size == 0:
        raise DataError("no heading samples after start_s")
    turned = np.abs(h - h[okh[0]])
    notes = []
    hit = first_crossing(t, turned, TURN_RAD)
    if hit is None:
        _check_coverage(t, observed_until_s, frame_s)
        time_s, completed = CAP_S, False
    else:
        time_s, completed = hit[0], True
        note = _gap_note(t, turned, time_s, max_gap_s, "the 360 degree mark")
        if note:
            notes.append(note)
    sel = t <= time_s + 1e-9
    # include the interpolated end point so the fit covers exactly [0, time_s]
    xe, ye = _interp_at(t, x, time_s), _interp_at(t, y, time_s)
    try:
        cx, cy, r = fit_circle(np.append(x[sel], xe), np.append(y[sel], ye))
    except NoCircleError as exc:
        # a turn trial that swam straight: its time (60 s, not completed) is a score; its radius is none
        notes.append(f"no radius: {exc}")
        return TrialScore(task="turn", time_s=float(time_s), completed=completed, radius_m=None,
                          circle_center=None, notes=tuple(notes))
    if r > 1.0:
        notes.append(f"the path hardly curves (fitted radius {r:.2f} m): the radius is ill-conditioned")
    return TrialScore(task="turn", time_s=float(time_s), completed=completed, radius_m=r,
                      circle_center=(cx, cy), notes=tuple(notes))


def score_trajectory(task: str, t, x, y, heading_rad, **kwargs) -> TrialScore:
    """Dispatch on the task (``straight`` or ``turn``)."""
    if task == "straight":
        return score_straight(t, x, y, **kwargs)
    if task == "turn":
        return score_turn(t, x, y, heading_rad, **kwargs)
    raise DataError(f"unknown task {task!r}")
