"""Clock alignment by pairing rising trigger edges (contract section 1, "The trigger line").

The controller raises the shared trigger line on the tick a run starts and every 1.000 s of its
clock after that. Its own log rows are its ticks, so its rising edges are exact. Every other
device samples the line; the true edge lies between its last low and first high sample, and the
midpoint of the two is the estimate (error uniform within one sample period). A least-squares
line ``device = a + b * controller`` through the midpoints of all paired edges averages those
errors down when the sampling phase varies from edge to edge (jitter, drift).

When it barely varies (a steady controller, a clock drifting by tens of ppm over a short run),
the midpoints' errors share a sign and the least-squares line can miss by more than half a
sample at the ends of the run. The bracketing samples hold more than their midpoint, though:
the true line must pass through every edge's (last low, first high] interval. Among the lines
that do, ingest takes the one whose values at the first and at the last paired edge sit in the
middle of their feasible ranges; that bounds the error at both ends, hence everywhere between,
by half the narrowest feasible range (at most half a sample, usually much less). When no line
fits every interval (a device clock that jitters), the least-squares line is used; the quality
report says which (``clock_fit``).

Pairing never correlates signals (that would hide real physical delays). The device's first
edge is the run's first edge when the device saw the line low for longer than any low stretch
inside the pulse train (0.9 s), or when both logs hold the same number of edges; otherwise the
pairing is ambiguous and the run is refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workbench.contract.columns import TRIGGER_HIGH_S, TRIGGER_PERIOD_S
from workbench.errors import DataError

#: a low stretch this long (device s) can only be the line before the run: inside the pulse train
#: the line is low for TRIGGER_PERIOD_S - TRIGGER_HIGH_S = 0.9 s
LEAD_IN_S = TRIGGER_PERIOD_S - TRIGGER_HIGH_S + 0.05
#: a predicted edge and a device edge further apart than this are not the same pulse
PAIR_TOLERANCE_S = 0.3 * TRIGGER_PERIOD_S


@dataclass(frozen=True)
class ClockFit:
    """A device clock against the controller clock: ``device = a + b * controller``.

    ``offset_s`` is device minus controller time at the run's first trigger edge (``start_s``
    on the controller clock); ``drift`` is ``b - 1`` (device seconds gained per controller second).
    """

    a: float
    b: float
    start_s: float
    n_edges: int
    residual_max_s: float
    residual_rms_s: float
    #: "bounded" (centred in the set of lines through every edge interval) or "least_squares"
    method: str = "least_squares"

    @property
    def offset_s(self) -> float:
        """Device minus controller time at the run's first edge (s)."""
        return self.a + (self.b - 1.0) * self.start_s

    @property
    def drift(self) -> float:
        """Relative rate error of the device clock (dimensionless)."""
        return self.b - 1.0

    def to_controller(self, t_device: np.ndarray) -> np.ndarray:
        """Map device times onto the controller clock."""
        return (np.asarray(t_device, float) - self.a) / self.b


def controller_edges(t: np.ndarray, sync: np.ndarray) -> np.ndarray:
    """Indices of the rows where the controller raised the line (0 -> 1); their times are exact."""
    s = np.asarray(sync) > 0
    return np.flatnonzero(~s[:-1] & s[1:]) + 1


def sampled_edges(t: np.ndarray, sync: np.ndarray) -> np.ndarray:
    """Rising-edge time estimates of a sampling device: midpoints of last-low and first-high samples."""
    i = controller_edges(t, sync)
    t = np.asarray(t, float)
    return 0.5 * (t[i - 1] + t[i])


def pair_edges(ctrl: np.ndarray, dev: np.ndarray, dev_span: tuple[float, float], ctrl_end: float,
               anchored: bool) -> tuple[np.ndarray, np.ndarray, str | None]:
    """Pair controller edge times with device edge times, walking forward from the first pair.

    Returns indices (ci, di) and a fault description or None. ``dev_span`` is the device log's
    time span; controller edges predicted outside it are simply not seen by the device.
    """
    if len(ctrl) == 0:
        return np.zeros(0, int), np.zeros(0, int), "no rising trigger edge in the controller log"
    if len(dev) == 0:
        return np.zeros(0, int), np.zeros(0, int), "no rising trigger edge"
    if not anchored:
        return np.zeros(0, int), np.zeros(0, int), (
            "cannot tell which trigger pulse is the run's first: the log starts inside the pulse train "
            f"(needs {LEAD_IN_S:.2f} s of low trigger line before the run)")
    ci, di = [0], [0]
    rate = 1.0
    for k in range(1, len(ctrl)):
        pred = dev[di[-1]] + (ctrl[k] - ctrl[ci[-1]]) * rate
        if pred > dev_span[1]:
            break  # the device stopped logging before this pulse
        j = int(np.searchsorted(dev, pred))
        cands = [c for c in (j - 1, j) if 0 <= c < len(dev)]
        best = min(cands, key=lambda c: abs(dev[c] - pred)) if cands else None
        if best is None or abs(dev[best] - pred) > PAIR_TOLERANCE_S or best <= di[-1]:
            if pred > dev_span[1] - TRIGGER_HIGH_S:
                break  # the pulse started too close to the end of the device log to be seen
            return np.asarray(ci), np.asarray(di), (
                f"missing trigger edge: the controller raised the line at {ctrl[k]:.3f} s (its clock) "
                f"but no rising edge is near {pred:.3f} s (device clock)")
        ci.append(k)
        di.append(best)
        if ctrl[k] - ctrl[0] >= 2 * TRIGGER_PERIOD_S:
            rate = (dev[di[-1]] - dev[di[0]]) / (ctrl[ci[-1]] - ctrl[ci[0]])
    ci_a, di_a = np.asarray(ci), np.asarray(di)
    # device edges the controller never made (while its log was running) mean a broken line
    last_dev_in_ctrl = dev[di_a[-1]] + (ctrl_end - ctrl[ci_a[-1]]) * rate
    extra = np.setdiff1d(np.flatnonzero(dev <= last_dev_in_ctrl), di_a)
    if len(extra):
        return ci_a, di_a, f"trigger edge at {dev[extra[0]]:.3f} s (device clock) has no controller edge"
    return ci_a, di_a, None


def align_clock(ctrl_t: np.ndarray, ctrl_sync: np.ndarray, dev_t: np.ndarray, dev_sync: np.ndarray, *,
                path=None, run: str | None = None, max_residual_ms: float = 3.0) -> ClockFit:
    """Fit the device clock against the controller clock from their rising trigger edges.

    Raises :class:`DataError` (naming the device file and run) when edges are missing, cannot be
    paired, or do not lie on a line.
    """
    ctrl_t = np.asarray(ctrl_t, float)
    dev_t = np.asarray(dev_t, float)
    if np.asarray(ctrl_sync)[0] > 0:
        raise DataError("controller log starts with the trigger line high; it must start before the run",
                        path=path, run=run, hint="the contract has the line low before the run")
    c = ctrl_t[controller_edges(ctrl_t, ctrl_sync)]
    dev_idx = controller_edges(dev_t, dev_sync)
    d = 0.5 * (dev_t[dev_idx - 1] + dev_t[dev_idx])
    anchored = False
    if len(d):
        first = int(dev_idx[0])
        high_before = np.flatnonzero(np.asarray(dev_sync)[:first] > 0)
        low_from = int(high_before[-1]) + 1 if len(high_before) else 0
        lead_in = dev_t[first - 1] - dev_t[low_from]
        anchored = lead_in >= LEAD_IN_S or (len(d) == len(c) and low_from == 0)
    ci, di, fault = pair_edges(c, d, (dev_t[0], dev_t[-1]), ctrl_t[-1], anchored)
    if fault is None and len(ci) < 2:
        fault = f"only {len(ci)} trigger edge(s) paired; need at least 2 for offset and drift"
    if fault:
        raise DataError(fault, path=path, run=run)
    x, y = c[ci], d[di]
    lo, hi = dev_t[dev_idx[di] - 1], dev_t[dev_idx[di]]
    x0 = x[0]
    b, a0 = np.polyfit(x - x0, y, 1)
    method = "least_squares"
    bounded = _bounded_line(x - x0, lo, hi)
    if bounded is not None:
        a0, b = bounded
        method = "bounded"
    a = a0 - b * x0
    resid = y - (a + b * x)
    worst = float(np.max(np.abs(resid)))
    if worst * 1e3 > max_residual_ms:
        k = int(np.argmax(np.abs(resid)))
        raise DataError(f"trigger edges do not lie on one clock line: edge at {x[k]:.3f} s (controller) is off by "
                        f"{worst * 1e3:.1f} ms (limit {max_residual_ms:g} ms)", path=path, run=run,
                        hint="a clock jump or a misread trigger line")
    return ClockFit(a=float(a), b=float(b), start_s=float(x0), n_edges=len(ci), residual_max_s=worst,
                    residual_rms_s=float(np.sqrt(np.mean(resid ** 2))), method=method)


#: the bracketing intervals are widened by this much (device time stamps rounded to microseconds)
_SLACK_S = 2e-6
_GRID = 65


def _feasible(y: np.ndarray, dx: np.ndarray, lo_k: np.ndarray, hi_k: np.ndarray) -> np.ndarray:
    """Whether each candidate value ``y`` at the anchor edge leaves a slope meeting every other interval."""
    y = y[:, None]
    bound_a, bound_b = (lo_k - y) / dx, (hi_k - y) / dx
    s_lo = np.max(np.where(dx > 0, bound_a, bound_b), axis=1)
    s_hi = np.min(np.where(dx > 0, bound_b, bound_a), axis=1)
    return s_lo <= s_hi


def _feasible_range(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, m: int) -> tuple[float, float] | None:
    """Range of values at ``x[m]`` of the lines passing through every interval (lo_k, hi_k] at x_k.

    The feasible values form an interval (the set of lines is convex): found on a coarse grid over
    the anchor's own interval, then each end refined on a fine grid between its neighbours.
    """
    dx = np.delete(x - x[m], m)[None, :]
    lo_k, hi_k = np.delete(lo, m)[None, :], np.delete(hi, m)[None, :]
    y = np.linspace(lo[m], hi[m], _GRID)
    ok = np.flatnonzero(_feasible(y, dx, lo_k, hi_k))
    if len(ok) == 0:
        return None
    ends = []
    for i, j in ((ok[0], ok[0] - 1), (ok[-1], ok[-1] + 1)):
        if 0 <= j < len(y):
            fine = np.linspace(y[j], y[i], _GRID)
            ends.append(fine[np.argmax(_feasible(fine, dx, lo_k, hi_k))])
        else:
            ends.append(y[i])
    return float(ends[0]), float(ends[1])


def _bounded_line(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> tuple[float, float] | None:
    """Intercept at x = 0 and slope of the line centred in the feasible set, or None if it is empty."""
    lo, hi = lo - _SLACK_S, hi + _SLACK_S
    first = _feasible_range(x, lo, hi, 0)
    last = _feasible_range(x, lo, hi, len(x) - 1)
    if first is None or last is None:
        return None
    y0, y1 = 0.5 * sum(first), 0.5 * sum(last)
    slope = (y1 - y0) / (x[-1] - x[0])
    return y0 - slope * x[0], slope
