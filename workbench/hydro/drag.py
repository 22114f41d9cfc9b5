"""Body drag from a towing-tank campaign (paper section III-D): steady stretches, run means, quadratic fit.

Each run tows the robot along its +y (``forward``) or +x (``lateral``) at a constant carriage
speed. The steady stretch is found from the carriage speed alone (a robust plateau: median
filter, the typical speed of the moving samples, the longest stretch within a tolerance of it,
trimmed at both ends); the force along the towing direction is averaged over it, with a
standard error from batch means (the force is filtered and autocorrelated, so samples are not
independent). Drag is reported as a positive magnitude: the load cell reads the hydrodynamic
force on the robot, which points against the towing direction, so drag = -mean(fy) forward and
-mean(fx) lateral. Per heading, weighted least squares fits F = c2 v^2 + c1 v + c0 with
standard errors, R^2, a confidence band and flags for physically doubtful fits.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal, Mapping

import numpy as np

from workbench.errors import ContractError, DataError

HEADING_CHANNEL = {"forward": "fy_n", "lateral": "fx_n"}


@dataclass(frozen=True)
class PlateauSettings:
    """How the steady-speed stretch of a run is found (``pipelines/drag.yaml`` fit.plateau)."""

    #: median-filter window for the carriage speed (s)
    smooth_s: float = 0.25
    #: a tick is steady when |v - v_plateau| <= max(rel_tol * v_plateau, abs_tol_mps)
    rel_tol: float = 0.03
    abs_tol_mps: float = 0.005
    #: dropped after the stretch starts (the force settles after the acceleration) and before it ends (s)
    settle_s: float = 0.5
    end_trim_s: float = 0.2
    #: shortest usable stretch after trimming (s)
    min_duration_s: float = 1.0


@dataclass(frozen=True)
class DragFitSettings:
    """Drag-fit settings (``pipelines/drag.yaml`` section ``fit``)."""

    plateau: PlateauSettings = field(default_factory=PlateauSettings)
    #: Sokal's window for the integrated autocorrelation time behind a run's standard error
    acf_window_c: float = 5.0
    #: "sem": weight runs by 1/SEM^2; "none": ordinary least squares
    weighting: Literal["sem", "none"] = "sem"
    #: floor on a run's standard error (N), so a noise-free run cannot take all the weight
    sigma_floor_n: float = 1e-3
    confidence: float = 0.95
    #: flags: R^2 below, fewer distinct speeds than, chi^2/dof above, plateau speed off the manifest's by more than
    min_r2: float = 0.95
    min_speeds: int = 5
    max_chi2_red: float = 4.0
    speed_mismatch: float = 0.10
    #: subtract the load cell's zero, read while the carriage rests before (and after) the tow: needs
    #: tare_min_s of rest, ending tare_margin_s before the carriage moves (the low-pass filter smears
    #: the force step of the start); with rest at both ends the zero is interpolated linearly in time
    tare: bool = True
    tare_min_s: float = 0.5
    tare_margin_s: float = 0.5

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any] | None) -> "DragFitSettings":
        """From the parsed ``fit`` section (workbench.params: unknown keys, wrong types are a ParamsError)."""
        from workbench.params import build

        return build(cls, doc, key="fit")


#: the names before issue 17 (settings classes end in ``Settings``); kept for existing imports
DragFitParams = DragFitSettings
PlateauParams = PlateauSettings


@dataclass(frozen=True)
class RunPoint:
    """One towing run reduced to (speed, drag)."""

    run_id: str
    heading: str
    speed_mps: float
    nominal_speed_mps: float
    drag_n: float
    drag_sem_n: float
    window_s: tuple[float, float]
    n_samples: int
    notes: tuple[str, ...] = ()


@dataclass(frozen=True)
class HeadingFit:
    """F = c2 v^2 + c1 v + c0 for one towing heading."""

    heading: str
    coefficients: tuple[float, float, float]
    stderr: tuple[float, float, float]
    covariance: np.ndarray
    r2: float
    dof: int
    chi2_red: float
    t_crit: float
    points: tuple[RunPoint, ...]
    n_speeds: int
    flags: tuple[str, ...]

    @property
    def speed_range_mps(self) -> tuple[float, float]:
        """Lowest and highest towed speed."""
        v = [p.speed_mps for p in self.points]
        return min(v), max(v)

    def predict(self, v) -> np.ndarray:
        """Fitted drag (N) at speeds v (m/s)."""
        return np.polyval(self.coefficients, np.asarray(v, float))

    def band(self, v) -> tuple[np.ndarray, np.ndarray]:
        """Confidence band of the fitted mean drag at speeds v (lower, upper)."""
        v = np.asarray(v, float)
        g = np.stack([v**2, v, np.ones_like(v)], axis=-1)
        half = self.t_crit * np.sqrt(np.einsum("...i,ij,...j->...", g, self.covariance, g))
        f = self.predict(v)
        return f - half, f + half

    def to_json(self) -> dict:
        """The contract's entry (coefficients, stderr, r2) plus diagnostics."""
        return {
            "coefficients": [float(c) for c in self.coefficients],
            "stderr": [_finite(s) for s in self.stderr],
            "r2": _finite(self.r2),
            "n_runs": len(self.points),
            "n_speeds": self.n_speeds,
            "speed_range_mps": [float(v) for v in self.speed_range_mps],
            "dof": self.dof,
            "chi2_red": _finite(self.chi2_red),
            "covariance": [[_finite(c) for c in row] for row in self.covariance],
            "flags": list(self.flags),
            "points": [{"run_id": p.run_id, "speed_mps": p.speed_mps, "drag_n": p.drag_n,
                        "drag_sem_n": p.drag_sem_n, "window_s": list(p.window_s), "n_samples": p.n_samples,
                        **({"notes": list(p.notes)} if p.notes else {})} for p in self.points],
        }


@dataclass(frozen=True)
class DragFit:
    """Both headings' fits and the runs that could not be used."""

    forward: HeadingFit
    lateral: HeadingFit
    skipped: tuple[tuple[str, str], ...]
    params: DragFitSettings

    def headings(self) -> tuple[HeadingFit, HeadingFit]:
        """(forward, lateral)."""
        return self.forward, self.lateral

    def to_json(self) -> dict:
        """``drag.json`` (data contract section 4) with extra diagnostic keys."""
        return {
            "forward": self.forward.to_json(),
            "lateral": self.lateral.to_json(),
            "model": "F = c2 v^2 + c1 v + c0 (N, v in m/s), drag as a positive magnitude",
            "skipped_runs": [{"run_id": r, "reason": why} for r, why in self.skipped],
            "params": asdict(self.params),
        }


def _finite(x: float) -> float | None:
    """JSON has no NaN: undefined numbers become null."""
    x = float(x)
    return x if math.isfinite(x) else None


# -- plateau and run means ---------------------------------------------------------------------
def _smooth_speed(t: np.ndarray, v: np.ndarray, params: PlateauSettings) -> np.ndarray:
    """Median-filtered carriage speed (robust to glitches in a differenced position log)."""
    from scipy.ndimage import median_filter

    dt = float(np.median(np.diff(t)))
    return median_filter(v, size=max(1, int(round(params.smooth_s / dt))) | 1, mode="nearest")


def steady_window(time_s: np.ndarray, speed_mps: np.ndarray, params: PlateauSettings = PlateauSettings()
                  ) -> tuple[slice | None, float, str]:
    """The steady-speed stretch of one run: (slice of ticks or None, plateau speed, reason if None)."""
    t = np.asarray(time_s, float)
    v = np.asarray(speed_mps, float)
    if t.size < 3:
        return None, float("nan"), "fewer than 3 samples"
    if not np.all(np.diff(t) > 0):
        return None, float("nan"), "time does not increase"
    s = _smooth_speed(t, v, params)
    top = float(np.quantile(s, 0.99))
    if not top > params.abs_tol_mps:
        return None, float("nan"), "the carriage never moved"
    v_ref = float(np.median(s[s >= 0.5 * top]))
    for _ in range(2):  # refine on the samples near the first guess
        tol = max(params.rel_tol * v_ref, params.abs_tol_mps)
        near = np.abs(s - v_ref) <= tol
        v_ref = float(np.median(s[near]))
    tol = max(params.rel_tol * v_ref, params.abs_tol_mps)
    near = np.abs(s - v_ref) <= tol
    edges = np.diff(np.concatenate([[0], near.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    longest = int(np.argmax(ends - starts))
    i0, i1 = int(starts[longest]), int(ends[longest])
    i0 = int(np.searchsorted(t, t[i0] + params.settle_s))
    i1 = int(np.searchsorted(t, t[i1 - 1] - params.end_trim_s, side="right"))
    if i1 - i0 < 3 or t[i1 - 1] - t[i0] < params.min_duration_s:
        return None, v_ref, (f"steady stretch at {v_ref:.3f} m/s is shorter than "
                             f"{params.min_duration_s:g} s after trimming")
    return slice(i0, i1), v_ref, ""


def rest_offset(time_s: np.ndarray, speed_mps: np.ndarray, force: np.ndarray, window: slice,
                params: DragFitSettings) -> tuple[np.ndarray, float] | None:
    """The load cell's zero over ``window`` and the standard error of its mean there (None: no rest).

    The zero is read while the carriage rests before and after the tow. The carriage moves where
    its smoothed speed exceeds ``abs_tol_mps`` (the same threshold at every towing speed, so the
    margins do not depend on the speed); a rest stretch must end (or start) ``tare_margin_s`` away
    from the motion and last ``tare_min_s``. With both stretches the zero is interpolated linearly
    in time (a drifting load cell), with one it is constant.
    """
    t = np.asarray(time_s, float)
    s = _smooth_speed(t, np.asarray(speed_mps, float), params.plateau)
    moving = np.flatnonzero(s > params.plateau.abs_tol_mps)
    if moving.size == 0:
        return None
    anchors = []
    for rest in (t < t[moving[0]] - params.tare_margin_s, t > t[moving[-1]] + params.tare_margin_s):
        if rest.sum() >= 2 and np.ptp(t[rest]) >= params.tare_min_s:
            anchors.append((float(t[rest].mean()), float(force[rest].mean()),
                            mean_sem(force[rest], params.acf_window_c)))
    if not anchors:
        return None
    tw = t[window]
    if len(anchors) == 1:
        return np.full(tw.shape, anchors[0][1]), anchors[0][2]
    (t0, f0, s0), (t1, f1, s1) = anchors
    w = (tw - t0) / (t1 - t0)
    wm = float(w.mean())
    return f0 + (f1 - f0) * w, math.hypot((1 - wm) * s0, wm * s1)


def mean_sem(x: np.ndarray, c: float = 5.0) -> float:
    """Standard error of the mean of an autocorrelated series (integrated autocorrelation time).

    tau = 1 + 2 sum_k rho_k, summed up to the smallest lag M >= c tau (Sokal's automatic window);
    SEM = sqrt(var tau / N). Subtracting the sample mean biases every rho_k low, which shortens
    tau on short records; tau is divided by max(1 - 1.5 (M + 1/2) / N, 1/2), a correction calibrated on
    first-order (AR(1)) noise to within about 10 % for records longer than ten correlation times
    (tests/hydro/test_drag.py). The force is low-pass filtered and carries slow wake fluctuations,
    so sigma / sqrt(N) would be far too small.
    """
    x = np.asarray(x, float)
    n = x.size
    if n < 4:
        return float(np.std(x, ddof=1) / math.sqrt(n)) if n > 1 else float("nan")
    d = x - x.mean()
    nfft = 1 << (2 * n - 1).bit_length()
    spec = np.fft.rfft(d, nfft)
    acf = np.fft.irfft(spec * np.conj(spec), nfft)[:n]
    if acf[0] <= 0:
        return 0.0
    taus = 2.0 * np.cumsum(acf / acf[0]) - 1.0
    ok = np.flatnonzero(np.arange(n) >= c * taus)
    m = int(ok[0]) if ok.size else n - 1
    tau = float(taus[m]) / max(1.0 - 1.5 * (m + 0.5) / n, 0.5)
    tau = min(max(tau, 1.0), float(n))
    return float(math.sqrt(acf[0] / n * tau / n))


def run_points(frame, headings: Mapping[str, str] | None = None, params: DragFitSettings = DragFitSettings()
               ) -> tuple[list[RunPoint], list[tuple[str, str]]]:
    """Reduce every run of a processed towing frame to a :class:`RunPoint`; also return skipped runs.

    The heading comes from a ``heading`` column or else from ``headings`` (run id -> heading,
    e.g. from the campaign manifest). Speed is the ``speed_mps`` column (else differenced from
    ``position_m``); the manifest speed (``flow_speed_mps``) only serves as a cross-check.
    """
    import polars as pl

    _check_towing_columns(frame)
    if "interpolated" in frame.columns:
        frame = frame.filter(~pl.col("interpolated"))
    points: list[RunPoint] = []
    skipped: list[tuple[str, str]] = []
    for (run_id,), g in frame.group_by(["run_id"], maintain_order=True):
        run_id = str(run_id)
        g = g.sort("time_s")
        point, why = _run_point(run_id, g, _run_heading(g, run_id, headings), params)
        if point is None:
            skipped.append((run_id, why))
        else:
            points.append(point)
    return points, skipped


def _check_towing_columns(frame) -> None:
    """Refuse a towing frame without run id, time, both force channels, and speed or position."""
    need = {"run_id", "time_s"} | set(HEADING_CHANNEL.values())
    missing = sorted(need - set(frame.columns))
    if missing:
        raise ContractError(f"processed towing frame lacks columns {missing}")
    if "speed_mps" not in frame.columns and "position_m" not in frame.columns:
        raise ContractError("processed towing frame has neither speed_mps nor position_m")


def _run_heading(g, run_id: str, headings: Mapping[str, str] | None) -> str:
    """The run's towing heading: its ``heading`` column, else the manifest's; anything else is a ``DataError``."""
    heading = str(g["heading"][0]) if "heading" in g.columns else (headings or {}).get(run_id)
    if heading not in HEADING_CHANNEL:
        raise DataError(f"heading {heading!r} is not forward or lateral", run=run_id,
                        hint="the manifest's heading names the towing direction")
    return heading


def _run_signals(g, heading: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Time, carriage speed (``speed_mps``, else the derivative of ``position_m``) and the heading's force."""
    t = g["time_s"].to_numpy().astype(float)
    if "speed_mps" in g.columns:
        v = g["speed_mps"].to_numpy().astype(float)
    else:
        v = np.gradient(g["position_m"].to_numpy().astype(float), t)
    return t, v, g[HEADING_CHANNEL[heading]].to_numpy().astype(float)


def _tare(t: np.ndarray, v: np.ndarray, force: np.ndarray, window: slice, params: DragFitSettings
          ) -> tuple[np.ndarray | float, float, str | None]:
    """The load cell's zero over ``window``, its standard error, and a note when it could not be read."""
    if not params.tare:
        return 0.0, 0.0, None
    rest = rest_offset(t, np.abs(v), force, window, params)
    if rest is None:
        return 0.0, 0.0, f"no {params.tare_min_s:g} s rest before or after the tow: not tared"
    return rest[0], rest[1], None


def _run_point(run_id: str, g, heading: str, params: DragFitSettings) -> tuple[RunPoint | None, str]:
    """One run reduced to its steady-stretch drag, or ``(None, why it was skipped)``."""
    t, v, force = _run_signals(g, heading)
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(v)) and np.all(np.isfinite(force))):
        return None, "non-finite samples"
    window, v_ref, why = steady_window(t, np.abs(v), params.plateau)
    if window is None:
        return None, why
    offset, offset_sem, note = _tare(t, v, force, window, params)
    notes = [] if note is None else [note]
    # the hydrodynamic force on the robot points against the tow: drag is its negative
    f = -(force[window] - offset)
    nominal = float(g["flow_speed_mps"][0]) if "flow_speed_mps" in g.columns else float("nan")
    speed = float(np.abs(v[window]).mean())
    if math.isfinite(nominal) and nominal > 0 and abs(speed - nominal) > params.speed_mismatch * nominal:
        notes.append(f"steady speed {speed:.3f} m/s differs from the manifest's {nominal:.3f} m/s")
    return RunPoint(run_id=run_id, heading=heading, speed_mps=speed, nominal_speed_mps=nominal,
                    drag_n=float(f.mean()), drag_sem_n=math.hypot(mean_sem(f, params.acf_window_c), offset_sem),
                    window_s=(float(t[window][0]), float(t[window][-1])),
                    n_samples=int(f.size), notes=tuple(notes)), ""


# -- the fit -------------------------------------------------------------------------------------
def _distinct_speeds(points: list[RunPoint]) -> int:
    keys = [round(p.nominal_speed_mps, 4) if math.isfinite(p.nominal_speed_mps) and p.nominal_speed_mps > 0
            else round(p.speed_mps, 3) for p in points]
    return len(set(keys))


def fit_heading(points: list[RunPoint], heading: str, params: DragFitSettings = DragFitSettings()) -> HeadingFit:
    """Weighted least squares F = c2 v^2 + c1 v + c0 over one heading's run points.

    With ``weighting: sem`` each run weighs 1/SEM^2 and the covariance is scaled by
    max(1, chi^2/dof): the runs' own noise sets the floor, and scatter between runs beyond it
    (run-to-run variation, model misfit) widens the errors. With ``none`` it is ordinary least
    squares with the residual variance. The band uses Student's t with n - 3 degrees of freedom.
    """
    from scipy import stats

    pts = [p for p in points if p.heading == heading]
    n_speeds = _distinct_speeds(pts)
    if len(pts) < 3 or n_speeds < 3:
        raise DataError(f"{heading} towing: {n_speeds} distinct speed(s) in {len(pts)} usable run(s); "
                        "a quadratic needs at least 3 speeds", hint="tow at more speeds")
    v = np.array([p.speed_mps for p in pts])
    f = np.array([p.drag_n for p in pts])
    if params.weighting == "sem":
        sem = np.array([p.drag_sem_n for p in pts])
        sigma = np.maximum(np.where(np.isfinite(sem), sem, 0.0), params.sigma_floor_n)
    else:
        sigma = np.ones_like(v)
    coef, cov_unscaled = np.polyfit(v, f, 2, w=1.0 / sigma, cov="unscaled")
    resid = f - np.polyval(coef, v)
    dof = len(pts) - 3
    chi2 = float(np.sum((resid / sigma) ** 2))
    chi2_red = chi2 / dof if dof > 0 else float("nan")
    if dof == 0:
        scale = 1.0 if params.weighting == "sem" else float("nan")
    else:
        scale = max(1.0, chi2_red) if params.weighting == "sem" else chi2_red
    cov = cov_unscaled * scale
    stderr = np.sqrt(np.diag(cov))
    ss_tot = float(np.sum((f - f.mean()) ** 2))
    r2 = 1.0 - float(np.sum(resid**2)) / ss_tot if ss_tot > 0 else float("nan")
    t_crit = float(stats.t.ppf(0.5 + params.confidence / 2, dof)) if dof > 0 else float("nan")
    fit = HeadingFit(heading=heading, coefficients=tuple(float(c) for c in coef),
                     stderr=tuple(float(s) for s in stderr), covariance=cov, r2=r2, dof=dof,
                     chi2_red=chi2_red, t_crit=t_crit, points=tuple(pts), n_speeds=n_speeds, flags=())
    return replace(fit, flags=tuple(doubtful(fit, params)))


def doubtful(fit: HeadingFit, params: DragFitSettings = DragFitSettings()) -> list[str]:
    """Plain-language flags for a fit that is physically doubtful or poorly supported."""
    flags = []
    c2, c1, c0 = fit.coefficients
    s2, _, s0 = fit.stderr
    lo, hi = fit.speed_range_mps
    crit = fit.t_crit if math.isfinite(fit.t_crit) else 2.0
    if math.isfinite(s0) and s0 > 0 and c0 / s0 > crit:
        zero = ("the runs were tared, so it is not a load-cell zero offset" if params.tare
                else "check the load cell's zero (fit.tare)")
        flags.append(f"drag at rest: intercept c0 = {c0:.3f} +- {s0:.3f} N is significantly above zero; a body at "
                     f"rest feels no drag, so trust the fit only over {lo:.2f}-{hi:.2f} m/s; {zero}")
    elif math.isfinite(s0) and s0 > 0 and c0 / s0 < -crit:
        flags.append(f"thrust at rest: intercept c0 = {c0:.3f} +- {s0:.3f} N is significantly below zero")
    if c2 < 0:
        sig = " (significantly)" if math.isfinite(s2) and s2 > 0 and -c2 / s2 > crit else ""
        flags.append(f"negative quadratic term c2 = {c2:.3f} N s^2/m^2{sig}: drag should grow like v^2")
    grid = np.linspace(lo, hi, 50)
    if np.any(np.polyval([2 * c2, c1], grid) < 0):
        flags.append(f"fitted drag decreases with speed somewhere in {lo:.2f}-{hi:.2f} m/s")
    if np.any(fit.predict(grid) <= 0) or np.mean([p.drag_n for p in fit.points]) < 0:
        flags.append("drag is negative: the force points along the tow; check the load cell's sign convention")
    if math.isfinite(fit.r2) and fit.r2 < params.min_r2:
        flags.append(f"poor fit: R^2 = {fit.r2:.3f} < {params.min_r2:g}")
    if fit.n_speeds < params.min_speeds:
        flags.append(f"few speeds: {fit.n_speeds} distinct towing speeds (< {params.min_speeds}); "
                     f"{fit.dof} degree(s) of freedom behind the standard errors")
    if math.isfinite(fit.chi2_red) and fit.chi2_red > params.max_chi2_red:
        flags.append(f"scatter between runs is {math.sqrt(fit.chi2_red):.1f}x their own noise "
                     f"(chi^2/dof = {fit.chi2_red:.1f}): run-to-run variation or a misfit; errors were widened")
    notes = [f"{p.run_id}: {n}" for p in fit.points for n in p.notes]
    if notes:
        flags.append("run notes: " + "; ".join(notes))
    return flags


def fit_drag(frame, *, headings: Mapping[str, str] | None = None,
             params: DragFitSettings = DragFitSettings()) -> DragFit:
    """Fit forward and lateral body drag from a processed towing-tank frame (data contract section 3)."""
    points, skipped = run_points(frame, headings, params)
    return DragFit(forward=fit_heading(points, "forward", params), lateral=fit_heading(points, "lateral", params),
                   skipped=tuple(skipped), params=params)
