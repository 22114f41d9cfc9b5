"""From raw marker pixels to a clean pose series on the water plane (pure numpy/scipy).

Position is the midpoint of the two markers and heading the tail-to-head direction (contract
section 2), both in tank metres. Outliers are rejected with a Hampel filter (a rolling median
and median absolute deviation), gaps up to ``max_gap_s`` are filled with a shape-preserving
cubic (PCHIP, so a brief occlusion does not overshoot), longer gaps stay NaN, and each
continuous stretch is smoothed with a Savitzky-Golay filter, which keeps the timing of a
crossing unbiased (a local polynomial, not a lagging average).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workbench.trials.geometry import apply_homography
from workbench.trials.params import ScoringSettings


@dataclass(frozen=True)
class PoseSeries:
    """Per-frame pose in the tank frame; NaN inside gaps longer than ``max_gap_s``."""

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    #: unwrapped, counter-clockwise from tank +X (radians)
    heading_rad: np.ndarray
    #: both markers seen and kept in this frame
    detected: np.ndarray
    #: value comes from gap filling
    filled: np.ndarray
    #: raw (unsmoothed) marker positions in tank metres, NaN when missing or rejected
    head_m: np.ndarray
    tail_m: np.ndarray

    def at(self, t: float) -> tuple[float, float, float]:
        """Interpolated ``(x, y, heading)`` at time ``t``; NaN when ``t`` lies in a gap."""
        out = []
        for a in (self.x_m, self.y_m, self.heading_rad):
            i = int(np.searchsorted(self.t_s, t))
            lo, hi = max(i - 1, 0), min(i, len(a) - 1)
            if not (np.isfinite(a[lo]) and np.isfinite(a[hi])):
                out.append(np.nan)
            elif hi == lo:
                out.append(float(a[lo]))
            else:
                w = (t - self.t_s[lo]) / (self.t_s[hi] - self.t_s[lo])
                out.append(float(a[lo] + w * (a[hi] - a[lo])))
        return out[0], out[1], out[2]


def _lstsq_cov(a: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares coefficients and their covariance, allowing for serially correlated errors.

    The residual variance is inflated by ``(1 + rho) / (1 - rho)`` for the residuals' lag-1
    autocorrelation ``rho`` (clipped to [0, 0.9]): video-compression errors of a slow marker
    persist over frames, and an iid standard error would call noise a kink.
    """
    coef, *_ = np.linalg.lstsq(a, y, rcond=None)
    resid = y - a @ coef
    rss = float(resid @ resid)
    dof = max(len(y) - a.shape[1], 1)
    rho = float(resid[1:] @ resid[:-1]) / rss if rss > 0 else 0.0
    rho = min(max(rho, 0.0), 0.9)
    cov = np.linalg.pinv(a.T @ a) * (rss / dof) * (1 + rho) / (1 - rho)
    return coef, cov


def start_heading(pose: PoseSeries, start_s: float, before_s: float, after_s: float, *,
                  kink_sigmas: float = 4.0) -> float:
    """Heading at ``start_s`` from a fit to the kept raw headings around it (NaN if too few).

    The robot rests or moves slowly there, so video-compression errors of the marker centroids
    change little from frame to frame and a short smoothing window cannot average them out; a
    fit over a few seconds can.

    The gait starts at ``start_s``, so the heading's *rate* may jump there (a turn starting at
    full rate): the heading is continuous but kinked. One polynomial across the kink is biased
    (a quadratic over [-1 s, +2 s] reads a step to rate w as 0.16 s x w, i.e. a 360 degree turn
    scored 0.16 s late, whatever w). Two fits are made: a quadratic across ``start_s``, and a
    model continuous at ``start_s`` with its own shape on each side (linear before, cubic after).
    The kinked model is used when the heading rate changes at ``start_s`` by more than
    ``kink_sigmas`` standard errors (measured with constant rates either side), the smooth one
    otherwise (it averages the noise better, about 1.7 times: straight runs).
    """
    d = pose.head_m - pose.tail_m
    ok = pose.detected & (pose.t_s >= start_s - before_s) & (pose.t_s <= start_s + after_s)
    if ok.sum() < 5:
        return float("nan")
    ang = np.arctan2(d[ok, 1], d[ok, 0])
    # unwrap near the smoothed heading so the fit sees a continuous angle
    ref = np.interp(pose.t_s[ok], pose.t_s, pose.heading_rad)
    ang = ref + (ang - ref + np.pi) % (2 * np.pi) - np.pi
    tt = pose.t_s[ok] - start_s
    order = 2 if np.ptp(tt) > 0.5 else 0
    smooth = float(np.polyval(np.polyfit(tt, ang, order), 0.0))
    kinked = kinked_value_at_start(tt, ang, after_s, kink_sigmas)
    return smooth if kinked is None else kinked


def kinked_value_at_start(tt: np.ndarray, v: np.ndarray, after_s: float, kink_sigmas: float) -> float | None:
    """Value at ``tt = 0`` from a fit allowing a kink there, or None when the data show no kink.

    The kink test fits constant rates either side of 0 (over at most 1 s after it): few
    parameters, so the rate change is measured precisely; a gradual ramp also shows as one. Its
    standard error allows for serially correlated residuals. With a kink, the value comes from
    a fit continuous at 0, linear before and cubic after (unbiased for a step or ramp in rate).
    """
    pre, post = tt[tt < 0], tt[tt >= 0]
    if pre.size < 4 or post.size < 6 or np.ptp(pre) < 0.25 or np.ptp(post) < 0.5:
        return None
    tm, tp = np.minimum(tt, 0.0), np.maximum(tt, 0.0)
    near = tt <= min(1.0, after_s)
    coef, cov = _lstsq_cov(np.column_stack([np.ones_like(tt), tm, tp])[near], v[near])
    g = np.array([0.0, -1.0, 1.0])
    jump, se = float(g @ coef), float(np.sqrt(max(g @ cov @ g, 0.0)))
    if not (se > 0 and abs(jump) > kink_sigmas * se):
        return None
    coef, _ = _lstsq_cov(np.column_stack([np.ones_like(tt), tm, tp, tp**2, tp**3]), v)
    return float(coef[0])


def start_position_along(pose: PoseSeries, start_s: float, before_s: float, after_s: float, heading_rad: float,
                         *, kink_sigmas: float = 4.0) -> float | None:
    """Position at ``start_s`` along ``heading_rad`` when the robot's speed jumps there, else None.

    A gait starting at full speed kinks the forward position at ``start_s``; the smoothed track
    (Savitzky-Golay, 0.5 s) rounds the kink and puts the start about 2.5 mm ahead at 0.1 m/s,
    so a straight run's 2 m crossing read 0.025 s late. When the forward coordinate's rate
    changes at ``start_s`` (the test of :func:`kinked_value_at_start`) this returns the
    kink-aware fit to the raw marker midpoints, projected on the heading; the lateral position
    stays the smoothed track's (it has no kink, and the smoothed value is less noisy).
    """
    ok = pose.detected & (pose.t_s >= start_s - before_s) & (pose.t_s <= start_s + after_s)
    if ok.sum() < 10:
        return None
    mid = 0.5 * (pose.head_m[ok] + pose.tail_m[ok])
    fwd = mid @ np.array([np.cos(heading_rad), np.sin(heading_rad)])
    return kinked_value_at_start(pose.t_s[ok] - start_s, fwd, after_s, kink_sigmas)


def _odd(n: float) -> int:
    n = int(round(n))
    return n if n % 2 == 1 else n + 1


def hampel_mask(v: np.ndarray, window: int, sigmas: float, floor: float) -> np.ndarray:
    """True where a finite sample deviates from its rolling median by more than the threshold.

    The threshold is ``max(sigmas * 1.4826 * MAD, floor)``; the window runs over finite samples.
    """
    from numpy.lib.stride_tricks import sliding_window_view

    out = np.zeros(v.shape, bool)
    idx = np.flatnonzero(np.isfinite(v))
    if idx.size < 5:
        return out
    w = min(_odd(window), _odd(idx.size) - 2 if idx.size > 2 else 1)
    w = max(w, 3)
    x = v[idx]
    pad = w // 2
    xp = np.pad(x, pad, mode="reflect")
    win = sliding_window_view(xp, w)
    med = np.median(win, axis=1)
    mad = np.median(np.abs(win - med[:, None]), axis=1)
    thr = np.maximum(sigmas * 1.4826 * mad, floor)
    out[idx] = np.abs(x - med) > thr
    return out


def fill_gaps(t: np.ndarray, v: np.ndarray, max_gap_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Fill NaN runs between finite samples no further apart than ``max_gap_s`` (PCHIP).

    Returns the filled series and a mask of the filled samples. Leading and trailing NaNs stay.
    """
    from scipy.interpolate import PchipInterpolator

    v = v.copy()
    filled = np.zeros(v.shape, bool)
    ok = np.flatnonzero(np.isfinite(v))
    if ok.size < 2:
        return v, filled
    gaps = np.flatnonzero(np.diff(ok) > 1)
    if gaps.size == 0:
        return v, filled
    f = PchipInterpolator(t[ok], v[ok])
    for g in gaps:
        a, b = ok[g], ok[g + 1]
        if t[b] - t[a] <= max_gap_s:
            v[a + 1:b] = f(t[a + 1:b])
            filled[a + 1:b] = True
    return v, filled


def smooth_segments(v: np.ndarray, window: int, order: int) -> np.ndarray:
    """Savitzky-Golay smoothing of each finite stretch (short stretches get shorter windows)."""
    from scipy.signal import savgol_filter

    out = v.copy()
    finite = np.isfinite(v)
    if not finite.any():
        return out
    edges = np.flatnonzero(np.diff(np.concatenate([[0], finite.astype(np.int8), [0]])))
    for a, b in zip(edges[::2], edges[1::2], strict=True):
        n = b - a
        w = min(_odd(window), n if n % 2 == 1 else n - 1)
        if w > order + 1:
            out[a:b] = savgol_filter(v[a:b], w, order, mode="interp")
    return out


def clean_pose(t_s: np.ndarray, head_px: np.ndarray, tail_px: np.ndarray, h_px2m: np.ndarray,
               params: ScoringSettings | None = None) -> PoseSeries:
    """Pose series from per-frame head and tail pixel positions (``(N, 2)``, NaN when missing)."""
    p = params or ScoringSettings()
    t = np.asarray(t_s, float)
    head = apply_homography(h_px2m, np.asarray(head_px, float))
    tail = apply_homography(h_px2m, np.asarray(tail_px, float))
    dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    both = np.all(np.isfinite(head), axis=1) & np.all(np.isfinite(tail), axis=1)
    mid = np.where(both[:, None], 0.5 * (head + tail), np.nan)
    d = head - tail
    heading = np.full(t.shape, np.nan)
    heading[both] = np.unwrap(np.arctan2(d[both, 1], d[both, 0]))
    # outliers: any coordinate of the pose off its rolling median
    win = p.hampel_window_s / dt
    bad = (hampel_mask(mid[:, 0], win, p.hampel_sigmas, p.hampel_floor_m)
           | hampel_mask(mid[:, 1], win, p.hampel_sigmas, p.hampel_floor_m)
           | hampel_mask(heading, win, p.hampel_sigmas, np.radians(p.hampel_floor_deg)))
    keep = both & ~bad
    x = np.where(keep, mid[:, 0], np.nan)
    y = np.where(keep, mid[:, 1], np.nan)
    hd = np.where(keep, heading, np.nan)
    if keep.any():
        # re-unwrap after dropping outliers so a rejected flip leaves no 2 pi step behind
        hd[keep] = np.unwrap(hd[keep])
    filled = np.zeros(t.shape, bool)
    series = []
    for v, win_s in ((x, p.smooth_window_s), (y, p.smooth_window_s), (hd, p.heading_window_s)):
        v2, f = fill_gaps(t, v, p.max_gap_s)
        filled |= f
        series.append(smooth_segments(v2, win_s / dt, p.smooth_order))
    raw_head = np.where(keep[:, None], head, np.nan)
    raw_tail = np.where(keep[:, None], tail, np.nan)
    return PoseSeries(t_s=t, x_m=series[0], y_m=series[1], heading_rad=series[2], detected=keep,
                      filled=filled, head_m=raw_head, tail_m=raw_tail)
