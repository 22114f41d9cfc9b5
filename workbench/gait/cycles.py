"""One steady cycle of a leg's wrench at constant flow, for many (gait shape, flow speed) pairs at once.

A gait *shape* is a leg's joint sinusoid without its phase: (theta_h_min, theta_k_max, f) plus the
fixed theta_h_max, theta_k_min and phi (paper eq. 3). Legs differing only in alpha share a shape,
so one cycle serves all four legs of a gait. Two ways to get the cycle, same numbers as a direct
rollout at constant flow:

* **window models** (a net that predicts each tick from the last ``seq_len`` ticks, like the
  FED-LSTM): the wrench at phase p is the net applied to the window of ticks ending at phase p,
  built from the analytic motion. Any number of phase samples, each one window: the cost does
  not grow with the cycle's length. See :func:`window_sampler`.
* **any other model** (e.g. one with unbounded memory): run the model on ``warmup`` ticks plus
  one cycle of the periodic motion at the simulation tick and keep the cycle (the warm-up lets
  the memory forget the start).

Either way every (shape, flow) pair of one request goes to the model in one batched call.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from workbench.errors import SettingError
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.motion import JointSinusoid, LegMotion


@dataclass(frozen=True)
class Shapes:
    """S distinct gait shapes: per-shape arrays (S,) and the fixed constants of equation 3."""

    theta_h_min_deg: np.ndarray
    theta_k_max_deg: np.ndarray
    frequency_hz: np.ndarray
    theta_h_max_deg: float
    theta_k_min_deg: float
    phi_rad: float

    def __len__(self) -> int:
        return int(self.frequency_hz.shape[0])

    def sinusoid(self, idx: np.ndarray) -> JointSinusoid:
        """Equation 3 for shapes ``idx`` (alpha = 0), parameters shaped (n, 1) to broadcast over time."""
        return JointSinusoid(self.theta_h_min_deg[idx, None], self.theta_h_max_deg, self.theta_k_min_deg,
                             self.theta_k_max_deg[idx, None], self.frequency_hz[idx, None], self.phi_rad, 0.0)


def motion_at(shapes: Shapes, idx: np.ndarray, tau_s: np.ndarray, flow_mps: np.ndarray, dt_s: float) -> LegMotion:
    """Analytic joint motion of shapes ``idx`` (n,) at times ``tau_s`` ((n, T) or (T,)), constant flow per row."""
    th, tk, wh, wk, ah, ak = shapes.sinusoid(idx).evaluate(tau_s)
    flow = np.broadcast_to(np.asarray(flow_mps, float)[:, None], th.shape)
    return LegMotion(float(dt_s), th, tk, wh, wk, np.ascontiguousarray(flow), ah, ak)


class WindowSampler:
    """Wrench at the last tick of each row of a short motion batch, for a window net.

    ``predict(motion (n, L)) -> (n, 6)`` equals ``model.wrench(longer motion)[:, -1]`` whenever the
    longer motion's last ``L`` ticks are these (the net sees nothing older). Built by
    :func:`window_sampler`, which checks that claim on the model before trusting it.
    """

    def __init__(self, seq_len: int, dt_s: float, predict: Callable[[LegMotion], np.ndarray]):
        self.seq_len = int(seq_len)
        self.dt_s = float(dt_s)
        self.predict = predict


def _learned_model_predict(model) -> Callable[[LegMotion], np.ndarray]:
    """Last-tick prediction of a :class:`workbench.learn.legmodel.LearnedLegModel` via its public parts.

    Mirrors ``LearnedLegModel.wrench``: features (flow, theta_h, theta_k, omega_h, omega_k),
    normalised, through ``predict_normalised``, de-normalised, plus the EF for the EF-residual
    variant. :func:`window_sampler` compares the result with ``model.wrench`` before use.
    """
    import torch

    xm, xs, ym, ys = model.norm.arrays()
    ef = None
    if getattr(model.model_cfg, "variant", None) == "ef_residual":
        from workbench.hydro.ef import EmpiricalFormula

        ef = EmpiricalFormula()

    def predict(motion: LegMotion) -> np.ndarray:
        n, length = motion.shape
        feats = np.stack([motion.flow_speed_mps, motion.theta_h_deg, motion.theta_k_deg,
                          motion.omega_h_dps, motion.omega_k_dps], axis=-1)
        xn = (feats.astype(np.float32) - xm) / xs
        flat = torch.from_numpy(np.ascontiguousarray(xn.reshape(n * length, -1)))
        ends = torch.arange(n) * length + (length - 1)
        out = model.predict_normalised(flat, ends).numpy().astype(np.float64) * ys
        if ef is None:
            return out + ym
        return out + ef.wrench(_last_tick(motion))[:, 0]

    return predict


def _last_tick(motion: LegMotion) -> LegMotion:
    def last(x):
        return None if x is None else x[:, -1:]

    return LegMotion(motion.dt_s, last(motion.theta_h_deg), last(motion.theta_k_deg), last(motion.omega_h_dps),
                     last(motion.omega_k_dps), last(motion.flow_speed_mps), last(motion.alpha_h_dps2),
                     last(motion.alpha_k_dps2))


def window_sampler(model: LegForceModel) -> WindowSampler | None:
    """A :class:`WindowSampler` for a window net, or None for a model of any other kind.

    A model may offer the hook ``window_wrench(motion (n, L)) -> (n, 6)`` (the wrench at each row's
    last tick) with attributes ``seq_len`` and ``dt_s``; a ``LearnedLegModel`` is served through its
    public parts. Either is accepted only if it reproduces ``model.wrench`` on a test motion.
    """
    seq_len, dt_s = getattr(model, "seq_len", None), getattr(model, "dt_s", None)
    if not seq_len or not dt_s:
        return None
    hook = getattr(model, "window_wrench", None)
    if callable(hook):
        predict = hook
    else:
        try:
            from workbench.learn.legmodel import LearnedLegModel
        except ImportError:
            return None
        if not isinstance(model, LearnedLegModel):
            return None
        predict = _learned_model_predict(model)
    sampler = WindowSampler(int(seq_len), float(dt_s), predict)
    return sampler if _agrees_with_model(model, sampler) else None


def _agrees_with_model(model: LegForceModel, sampler: WindowSampler) -> bool:
    """Whether the sampler gives ``model.wrench``'s last ticks on a few test motions (float32 nets: 1e-5)."""
    length = sampler.seq_len
    shapes = Shapes(np.array([-20.0, 5.0]), np.array([-50.0, -30.0]), np.array([0.5, 0.31]), -100.0, 80.0,
                    math.pi / 3)
    n_ticks = length + 5
    tau = (np.arange(n_ticks) - 3) * sampler.dt_s
    full = motion_at(shapes, np.array([0, 1]), tau, np.array([0.12, -0.03]), sampler.dt_s)
    want = model.wrench(full)[:, -3:]
    got = np.stack([sampler.predict(LegMotion(full.dt_s, *(None if x is None else x[:, e - length:e] for x in (
        full.theta_h_deg, full.theta_k_deg, full.omega_h_dps, full.omega_k_dps, full.flow_speed_mps,
        full.alpha_h_dps2, full.alpha_k_dps2)))) for e in (n_ticks - 2, n_ticks - 1, n_ticks)], axis=1)
    scale = max(float(np.abs(want).max()), 1e-9)
    return bool(np.all(np.isfinite(got)) and np.abs(got - want).max() <= 1e-5 * scale + 1e-9)


class CycleSource:
    """Computes steady cycles of a model's wrench for (shape, flow) pairs, sampled uniformly in phase.

    ``phase_step(shapes)`` gives each shape's sample spacing (cycles) and ``cycles(...)`` the samples
    at phases ``(j - 1) * step`` for j = 0 .. n_samples - 1 (one sample before phase 0 and a few past
    one cycle, so cubic interpolation needs no wrap-around).
    """

    def __init__(self, model: LegForceModel, *, sim_dt_s: float, phase_samples: int, warmup_s: float,
                 history_order: int = 2, history_phase_stride: int = 2, history_step_mps: float = 0.01):
        self.model = model
        self.sampler = window_sampler(model)
        self.sim_dt_s = float(sim_dt_s)
        self.phase_samples = int(phase_samples)
        self.warmup_s = float(warmup_s)
        #: window nets: flow-history terms tabulated besides the value (0 none, 1 slope, 2 + curvature)
        self.history_order = int(history_order) if self.sampler is not None else 0
        self.history_stride = int(history_phase_stride)
        self.history_step = float(history_step_mps)
        if self.history_order not in (0, 1, 2):
            raise SettingError("history_order must be 0, 1 or 2")
        if self.history_order and (self.history_stride < 1 or self.phase_samples % self.history_stride):
            raise SettingError("history_phase_stride must divide phase_samples")
        #: model calls, rows (pairs) and ticks (or windows) predicted so far
        self.calls = 0
        self.pairs = 0
        self.windows = 0

    @property
    def kind(self) -> str:
        """``window`` or ``rollout``."""
        return "window" if self.sampler is not None else "rollout"

    def phase_step(self, shapes: Shapes) -> np.ndarray:
        """Phase spacing (cycles) of each shape's samples: 1/P for window nets, f dt for rollouts."""
        if self.sampler is not None:
            return np.full(len(shapes), 1.0 / self.phase_samples)
        return shapes.frequency_hz * self.sim_dt_s

    def n_samples(self, shapes: Shapes) -> np.ndarray:
        """Samples per shape: phases -step .. >= 1 + 2 step."""
        step = self.phase_step(shapes)
        return (np.floor(1.0 / step + 1e-9).astype(int) + 4)

    @property
    def n_channels(self) -> int:
        """Table channels: the wrench (6), then per flow-history term its derivative (6 each)."""
        return 6 * (1 + self.history_order)

    def history_basis(self) -> np.ndarray:
        """(order, L) flow-history shapes over a window net's lags m = 0 .. L-1: (m / (L-1))^k, k = 1, 2."""
        length = self.sampler.seq_len
        lag = np.arange(length) / max(1, length - 1)
        return np.stack([lag ** k for k in range(1, self.history_order + 1)]) if self.history_order else \
            np.zeros((0, length))

    def history_filters(self) -> np.ndarray:
        """(1 + order, K) causal FIR taps on the simulation tick: the flow now, then history coefficients.

        The coefficients a_k are the least-squares fit sum_k a_k (m / (L-1))^k to the flow's change
        over the net's window (lags m). The tabulated wrench is then F(U(t)) + sum_k a_k dF/da_k: exact for a memoryless model, and
        for a window net exact to first order when the flow varies within the window like a
        quadratic, the part of a slowly varying flow that a constant-flow table misses.
        """
        s = self.sampler
        basis = self.history_basis()                                           # (order, L), zero at lag 0
        pinv = np.linalg.pinv(basis.T)                                         # (order, L)
        # fit of U(t - m) - U(t): row weights on the lags, minus their sum on lag 0
        weights = np.vstack([np.eye(1, s.seq_len), pinv])
        weights[1:, 0] -= pinv.sum(axis=1)
        # window lag m sits m * dt_net / dt_sim simulation ticks back: spread it over the two nearest
        pos = np.arange(s.seq_len) * s.dt_s / self.sim_dt_s
        k = int(np.ceil(pos[-1] + 1e-9)) + 1
        taps = np.zeros((weights.shape[0], k))
        lo = np.floor(pos + 1e-9).astype(int)
        frac = np.clip(pos - lo, 0.0, 1.0)
        for m in range(s.seq_len):
            taps[:, lo[m]] += weights[:, m] * (1 - frac[m])
            if frac[m] > 0:
                taps[:, lo[m] + 1] += weights[:, m] * frac[m]
        return taps

    def cycles(self, shapes: Shapes, idx: np.ndarray, flow_mps: np.ndarray, n_out: int) -> np.ndarray:
        """Samples (n, n_out, channels) of shapes ``idx`` at constant flows ``flow_mps`` (one model call)."""
        idx = np.asarray(idx, int)
        flow = np.asarray(flow_mps, float)
        self.calls += 1
        self.pairs += idx.size
        if self.sampler is not None:
            return self._window_cycles(shapes, idx, flow, n_out)
        return self._rollout_cycles(shapes, idx, flow, n_out)

    @property
    def memory_ticks(self) -> int:
        """Simulation ticks a model output can depend on: a window net's window, else the warm-up."""
        if self.sampler is not None:
            return int(math.ceil((self.sampler.seq_len - 1) * self.sampler.dt_s / self.sim_dt_s - 1e-9)) + 1
        return max(1, int(math.ceil(self.warmup_s / self.sim_dt_s - 1e-9)))

    def flow_kernel(self, shapes: Shapes | None = None, delta_mps: float = 0.01) -> np.ndarray:
        """How the model weighs the flow of past ticks: weights w_m (sum 1) of lags m = 0 .. memory - 1.

        Probes the model: steady motion at constant flow, the flow raised by ``delta_mps`` on one
        tick, and the response of the following ticks (all channels, several shapes, phases and
        speeds) condensed by least squares into one profile. A memoryless model gives [1, 0, ...].
        Tabulated wrenches read the table at the flow filtered by this profile, which is the
        first-order effect of a flow that varies within the model's memory.
        """
        k = self.memory_ticks
        if k <= 1:
            return np.ones(1)
        dt = self.sim_dt_s
        warm = k + int(math.ceil(self.warmup_s / dt)) if self.sampler is None else k
        shapes = shapes or Shapes(np.array([-50.0, -20.0, 10.0, -35.0]), np.array([-80.0, -50.0, -20.0, -30.0]),
                                  np.array([0.2, 0.45, 0.65, 0.3]), -100.0, 80.0, math.pi / 3)
        # two speeds, the flow raised at two phases of the cycle
        rows = [(flow, offset) for flow in (0.04, 0.14) for offset in (0.0, 0.37)]
        n = len(shapes) * len(rows)
        idx = np.repeat(np.arange(len(shapes)), len(rows))
        flows = np.tile([r[0] for r in rows], len(shapes))
        offs = np.tile([r[1] for r in rows], len(shapes))
        tau = (np.arange(warm + k)[None, :] - warm) * dt + offs[:, None] / shapes.frequency_hz[idx, None]
        base = motion_at(shapes, idx, tau, flows, dt)
        flow_pert = base.flow_speed_mps.copy()
        flow_pert[:, warm] += delta_mps
        def twice(x):
            return np.concatenate([x, x])

        both = LegMotion(dt, twice(base.theta_h_deg), twice(base.theta_k_deg), twice(base.omega_h_dps),
                         twice(base.omega_k_dps), np.concatenate([base.flow_speed_mps, flow_pert]),
                         twice(base.alpha_h_dps2), twice(base.alpha_k_dps2))
        out = np.asarray(self.model.wrench(both), float)
        resp = (out[n:, warm:] - out[:n, warm:]) / delta_mps                 # (n, K, 6)
        total = resp.sum(axis=1)                                              # (n, 6)
        denom = float((total * total).sum())
        if denom <= 0 or not np.isfinite(denom):
            return np.ones(1)
        w = np.einsum("nkc,nc->k", resp, total) / denom
        # drop the negligible tail (a memoryless model keeps one weight)
        keep = np.nonzero(np.abs(w) > 1e-4 * np.abs(w).max())[0]
        if not keep.size:
            return np.ones(1)
        w = w[:keep[-1] + 1]
        return w / w.sum()  # a constant flow reads the table at itself

    def _window_cycles(self, shapes, idx, flow, n_out):
        s = self.sampler
        p = self.phase_samples
        n = idx.size
        f = shapes.frequency_hz[idx]
        # window ending at phase k/P: ticks k/(P f) - (L-1-l) dt, l = 0..L-1
        ends = np.arange(p)[None, :] / (p * f[:, None])                    # (n, P)
        lags = (np.arange(s.seq_len) - (s.seq_len - 1)) * s.dt_s             # (L,)
        tau = (ends[:, :, None] + lags[None, None, :]).reshape(n, p * s.seq_len)
        motion = motion_at(shapes, idx, tau, flow, s.dt_s)

        def win(x, rows):
            return x.reshape(n, p, s.seq_len)[:, rows].reshape(-1, s.seq_len)

        # the constant-flow windows, then the flow-history perturbations at every stride-th phase
        d_rows = np.arange(0, p, self.history_stride)
        basis = self.history_basis()[:, ::-1]                                # over window ticks l (lag L-1-l)
        pieces = [(np.arange(p), np.zeros(s.seq_len))]
        pieces += [(d_rows, self.history_step * b) for b in basis]
        cols = [[], [], [], [], [], [], []]
        for rows, extra in pieces:
            for c, x in enumerate((motion.theta_h_deg, motion.theta_k_deg, motion.omega_h_dps, motion.omega_k_dps,
                                   motion.flow_speed_mps, motion.alpha_h_dps2, motion.alpha_k_dps2)):
                w = win(x, rows)
                cols[c].append(w + extra if c == 4 else w)
        windows = LegMotion(s.dt_s, *(np.concatenate(c) for c in cols))
        self.windows += windows.shape[0]
        out = np.asarray(s.predict(windows), float)
        base = out[:n * p].reshape(n, p, 6)
        parts = [base]
        at = n * p
        for _ in range(self.history_order):
            pert = out[at:at + n * d_rows.size].reshape(n, d_rows.size, 6)
            at += n * d_rows.size
            deriv = (pert - base[:, d_rows]) / self.history_step
            # back to every phase: periodic linear interpolation between the computed ones
            pos = np.arange(p) / self.history_stride
            i0 = np.floor(pos).astype(int)
            t = (pos - i0)[None, :, None]
            parts.append(deriv[:, i0 % d_rows.size] * (1 - t) + deriv[:, (i0 + 1) % d_rows.size] * t)
        table = np.concatenate(parts, axis=-1)                               # (n, P, channels)
        # sample j is phase (j - 1) / P: wrap around the periodic cycle
        j = (np.arange(n_out) - 1) % p
        return table[:, j]

    def _rollout_cycles(self, shapes, idx, flow, n_out):
        dt = self.sim_dt_s
        warm = int(math.ceil(self.warmup_s / dt))
        # ticks at (k - warm - 1) dt: sample j = k - warm sits at phase (j - 1) f dt
        tau = (np.arange(warm + n_out) - warm - 1) * dt
        motion = motion_at(shapes, idx, tau, flow, dt)
        self.windows += motion.shape[0] * motion.shape[1]
        out = np.asarray(self.model.wrench(motion), float)
        return out[:, warm:warm + n_out]
