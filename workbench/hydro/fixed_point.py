"""The fixed-point schemes of the simulator: growing windows with Anderson mixing (default), or Picard.

The flow history of all 4B legs is a fixed point flow = F(flow) (:class:`~workbench.hydro.leg_eval.FlowMap`).
:func:`windowed` solves it window by window (waveform relaxation), :func:`picard` over the whole
horizon at once; :func:`workbench.hydro.simulator.simulate` describes the schedule and calls them.
"""

from __future__ import annotations

import numpy as np

from workbench.hydro.body import BodyState
from workbench.hydro.gait_batch import GaitBatch
from workbench.hydro.leg_eval import FlowMap


def _periodic_guess(flow: np.ndarray, lo: int, hi: int, period_ticks: np.ndarray) -> None:
    """Fill ticks lo .. hi - 1 of ``flow`` (B, 4, T) with its own last gait cycle (in place).

    The legs' flow repeats with the gait once the swim settles, so flow(t) = flow(t - period) is a
    good first guess for a new stretch of the horizon; before one cycle is known, the last value is held.
    """
    if hi <= lo or lo == 0:
        return
    n = np.arange(lo, hi)
    for i, p in enumerate(period_ticks):
        src = n - p
        while np.any(src >= lo):  # windows longer than a cycle: reach back whole cycles
            src = np.where(src >= lo, src - p, src)
        if src.min() < 0:
            flow[i, :, lo:hi] = flow[i, :, lo - 1:lo]
            continue
        k = np.floor(src).astype(int)
        frac = src - k
        row = flow[i]
        row[:, lo:hi] = row[:, k] * (1 - frac) + row[:, np.minimum(k + 1, lo - 1)] * frac


def picard(solve: FlowMap, flow, tol_mps, max_iter, relaxation, on_iteration):
    """Whole-horizon relaxed Picard iteration (the earlier scheme); updates ``flow`` in place."""
    b = solve.b
    active = np.ones(b, bool)
    residual = np.full(b, np.inf)
    for k in range(1, max_iter + 1):
        w_leg = solve.wrench(flow)
        state, new_flow = solve.swim(w_leg)
        change = np.abs(new_flow - flow).max(axis=(1, 2))
        residual = np.where(active, change, residual)
        if on_iteration is not None:
            on_iteration(k, residual.copy())
        done = active & (change < tol_mps)
        active &= ~done
        if not active.any():
            break
        flow[:] = np.where(active[:, None, None], flow + relaxation * (new_flow - flow), flow)
    return w_leg, state, residual, k


#: no leg of a swimming robot sees a flow this fast (m/s); an iterate beyond it is diverging
FLOW_LIMIT_MPS = 5.0
#: the shortest window a retry uses (s)
MIN_WINDOW_S = 0.5
#: ticks at a window's end that are solved again with the next window (a leg model's one-tick look-ahead)
OVERLAP_TICKS = 2


def window_schedule(n_ticks: int, dt_s: float, window_s: float, max_window_s: float) -> list[tuple[int, int]]:
    """The windows (lo, hi) of ticks: ``window_s`` long, doubling up to ``max_window_s``, overlapping by 2 ticks.

    The schedule depends on the settings and the horizon only, never on the batch, so a gait's
    result does not depend on the other gaits it is simulated with.
    """
    width = max(OVERLAP_TICKS + 2, int(round(window_s / dt_s)))
    cap = max(width, int(round(max_window_s / dt_s)))
    out, lo = [], 0
    while True:
        hi = min(n_ticks, lo + width)
        out.append((lo, hi))
        if hi >= n_ticks:
            return out
        lo = hi - OVERLAP_TICKS
        width = min(2 * width, cap)


class _Anderson:
    """Anderson acceleration (type II, per gait) of the relaxed fixed-point step on a window's flow.

    With the last m iterates x_i and residuals f_i = F(x_i) - x_i, the step is
    w f - sum_i gamma_i (dx_i + w df_i), gamma minimising |f - sum gamma_i df_i| (least squares,
    lightly regularised). A gait whose residual grew restarts its history.
    """

    def __init__(self, b: int, depth: int):
        self.depth = depth
        self.dx: list[np.ndarray] = []
        self.df: list[np.ndarray] = []
        self.prev: tuple[np.ndarray, np.ndarray] | None = None

    def step(self, x: np.ndarray, f: np.ndarray, omega: np.ndarray, restart: np.ndarray) -> np.ndarray:
        if self.prev is not None:
            self.dx.append(x - self.prev[0])
            self.df.append(f - self.prev[1])
            if len(self.dx) > self.depth:
                self.dx.pop(0)
                self.df.pop(0)
        self.prev = (x.copy(), f.copy())
        w = omega[:, None]
        if not self.dx:
            return w * f
        dx, df = np.stack(self.dx, 1), np.stack(self.df, 1)          # (B, m, n)
        gram = df @ np.swapaxes(df, 1, 2)                             # (B, m, m)
        scale = np.trace(gram, axis1=1, axis2=2)[:, None, None] / gram.shape[1] + 1e-300
        gram = gram + 1e-10 * scale * np.eye(gram.shape[1])
        gamma = np.linalg.solve(gram, (df @ f[:, :, None]))[..., 0]    # (B, m)
        gamma = np.where(restart[:, None], 0.0, gamma)
        if restart.any():
            for arr in (*self.dx, *self.df):
                arr[restart] = 0.0
        return w * f - np.einsum("bm,bmn->bn", gamma, dx + w[:, None] * df)


def windowed(solve: FlowMap, flow, gaits: GaitBatch, tol_mps, max_iter, relaxation, window_s, max_window_s,
             failed, on_iteration, anderson: int = 0, guessed: bool = False) -> None:
    """Waveform relaxation on growing windows (see ``simulate``); updates ``flow`` and ``failed`` in place."""
    b, n_ticks, dt = solve.b, solve.n, solve.dt_s
    period = 1.0 / (gaits.frequency_hz * dt)           # ticks per gait cycle (not an integer)
    start = None                                        # the state at the window's first tick
    filled = n_ticks if guessed else 1                  # ticks with a first guess so far
    windows = window_schedule(n_ticks, dt, window_s, max_window_s)
    for j, (lo, hi) in enumerate(windows):
        guess_to = min(n_ticks, hi + OVERLAP_TICKS)
        if guess_to > filled:
            _periodic_guess(flow, filled, guess_to, period)
            filled = guess_to
        omega = np.full(b, relaxation)
        last = np.full(b, np.inf)
        active = ~failed
        state = None
        # this window's wrenches: frozen gaits keep theirs; gaits held or given up are not predicted (zero)
        w_win = np.zeros((b, 4, hi - lo, 6))
        acc = _Anderson(b, anderson) if anderson else None
        for _ in range(max_iter):
            w_win = solve.window_wrench(flow, lo, hi, active, w_win)
            state, new = solve.swim(w_win, lo, hi, start)
            x = flow[:, :, lo:hi]
            change = np.abs(new - x).max(axis=(1, 2))
            # a diverging gait (non-finite, or flows no swimmer sees) is given up before it poisons the batch
            wild = active & ~(np.abs(new).max(axis=(1, 2)) < FLOW_LIMIT_MPS)
            if wild.any():
                failed |= wild
                active &= ~wild
                change = np.where(wild, np.inf, change)
            if on_iteration is not None:
                on_iteration(solve.calls, np.where(active | wild, change, 0.0))
            grew = active & (change > last)
            omega = np.where(grew, np.maximum(0.5 * omega, 0.05), omega)
            last = np.where(active, change, last)
            active &= ~(change < tol_mps)
            if not active.any():
                break
            f = np.where(active[:, None, None], new - x, 0.0)
            step = omega[:, None, None] * f
            if acc is not None:
                step = acc.step(x.reshape(b, -1), f.reshape(b, -1), omega, grew).reshape(x.shape)
            nxt = x + step
            # an accelerated step that leaves the physical range falls back to the relaxed one
            wild_step = ~(np.abs(nxt).max(axis=(1, 2)) < FLOW_LIMIT_MPS)
            nxt = np.where(wild_step[:, None, None], x + omega[:, None, None] * f, nxt)
            flow[:, :, lo:hi] = np.where(active[:, None, None], nxt, x)
        failed |= active                               # not converged in its window: flagged, not iterated further
        if j + 1 < len(windows):
            start = BodyState.at(state, windows[j + 1][0] - lo)
