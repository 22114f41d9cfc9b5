"""Tabulated leg wrenches: a leg force model made cheap for a whole population's rollout.

Within one simulation each leg repeats its joint sinusoid; only the flow it sees changes, and
slowly. So for every gait *shape* (see :mod:`workbench.gait.cycles`) the wrapper computes one
steady cycle of the leg's wrench at each node of a flow-speed grid (nodes at k * ``flow_step``,
made lazily: only the nodes some leg's flow reaches, all missing (shape, node) pairs of one
fixed-point iteration in one model call), refines it once by Catmull-Rom interpolation (exact for
quadratics, which the drag term |V|V is between its kinks) onto a fine grid, and during the
rollout reads it bilinearly at each leg's phase and flow. The four legs of a gait share one
table: they differ only in alpha, i.e. in where they read it.

Two corrections keep it faithful to a direct rollout of a model with memory:

* **flow memory**: the table assumes a constant flow over the model's memory; the rollout reads
  it at the flow filtered by the model's own flow-weighting profile (measured once by probing the
  model, :meth:`CycleSource.flow_kernel`), which is exact to first order in the flow's variation;
* **start-up**: a direct rollout starts from a rest history (padded window, filter at rest), the
  table from the periodic steady state; the difference, computed once at zero flow (the robot
  starts at rest), is added to the first ticks.

docs/gaits.md and the tests measure what is left (objectives within 1 % of direct rollouts).

:class:`TabulatedLegModel` is a :class:`LegForceModel` bound to one :class:`GaitBatch`; it offers
``flow_provider(motion)`` (the simulator's hook), which checks that ``motion`` is the batch's,
so it plugs into :func:`workbench.hydro.simulator.simulate` unchanged.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Any, Callable, Mapping

import numpy as np

from workbench.errors import SettingError
from workbench.gait.cycles import CycleSource, Shapes
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.motion import LegMotion
from workbench.hydro.simulator import GaitBatch

TABULATION_MODES = ("auto", "always", "never")
INTERPOLATIONS = ("cubic", "linear")


@dataclass(frozen=True)
class TabulationSettings:
    """How leg wrenches are tabulated (``tabulation`` section of pipelines/gait.yaml)."""

    #: auto: tabulate models that offer no ``flow_provider`` of their own (the EF has an exact one)
    mode: str = "auto"
    #: spacing of the flow-speed nodes (m/s); nodes sit at integer multiples
    flow_step_mps: float = 0.05
    #: phase samples per cycle for window nets (the FED-LSTM); other models sample at the sim tick
    phase_samples: int = 48
    #: cubic (Catmull-Rom) or linear between the model's samples, in phase and in flow speed
    interpolation: str = "cubic"
    #: the fine grid read bilinearly during the rollout: samples per cycle (at least) ...
    fine_phase_samples: int = 192
    #: ... and fine steps per flow node interval
    fine_flow_factor: int = 4
    #: warm-up before the tabulated cycle for models that are not window nets (s)
    warmup_s: float = 1.0
    #: account for the flow varying within the model's memory (see the module docstring)
    flow_memory: bool = True
    #: window nets: flow-history terms tabulated with the value (1: slope, 2: slope and curvature)
    history_order: int = 2
    #: ... computed at every n-th phase sample (interpolated between)
    history_phase_stride: int = 2
    #: ... by finite differences of this size (m/s)
    history_step_mps: float = 0.01
    #: the first ticks (the model's memory) straight from the model at the actual flow: a direct
    #: rollout starts from a padded history, the table from the periodic steady state
    startup_correction: bool = True
    #: ... recomputed when their flow moved more than this since the last time (m/s; between: the
    #: table's change is added)
    startup_tol_mps: float = 0.005

    def __post_init__(self):
        if self.mode not in TABULATION_MODES:
            raise SettingError(f"tabulation.mode must be one of {TABULATION_MODES}, got {self.mode!r}")
        if self.interpolation not in INTERPOLATIONS:
            raise SettingError(f"tabulation.interpolation must be one of {INTERPOLATIONS}, got {self.interpolation!r}")
        if (self.flow_step_mps <= 0 or self.phase_samples < 4 or self.warmup_s < 0 or self.fine_flow_factor < 1
                or self.fine_phase_samples < 1 or self.history_step_mps <= 0 or self.startup_tol_mps < 0):
            raise SettingError("tabulation needs flow_step_mps > 0, phase_samples >= 4, warmup_s >= 0, "
                             "history_step_mps > 0, startup_tol_mps >= 0 and positive fine grid sizes")
        if self.history_order not in (0, 1, 2):
            raise SettingError("tabulation.history_order must be 0, 1 or 2")
        if self.history_phase_stride < 1 or self.phase_samples % self.history_phase_stride:
            raise SettingError("tabulation.history_phase_stride must divide phase_samples")

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any] | None, *, key: str = "optimize.tabulation",
                  path: str | None = None) -> "TabulationSettings":
        """From a ``tabulation`` section (workbench.params: unknown keys, wrong types, failed checks: ParamsError)."""
        from workbench.params import build

        return build(cls, doc, key=key, path=path)


def _kernel(t: np.ndarray, interpolation: str) -> tuple[np.ndarray, np.ndarray]:
    """Tap offsets (K,) and weights (..., K) for fractional positions ``t`` in [0, 1]."""
    if interpolation == "linear":
        return np.array([0, 1]), np.stack([1.0 - t, t], axis=-1)
    t2 = t * t
    t3 = t2 * t
    w = np.stack([(-t3 + 2 * t2 - t), (3 * t3 - 5 * t2 + 2), (-3 * t3 + 4 * t2 + t), (t3 - t2)], axis=-1) * 0.5
    return np.array([-1, 0, 1, 2]), w


def _resample(values: np.ndarray, axis: int, pos: np.ndarray, interpolation: str) -> np.ndarray:
    """``values`` interpolated along ``axis`` at fractional sample positions ``pos`` (kept inside the taps)."""
    n = values.shape[axis]
    offs, _ = _kernel(np.zeros(1), interpolation)
    lo, hi = -offs[0], n - 1 - offs[-1]              # first and last base index with all taps inside
    base = np.clip(np.floor(pos).astype(np.int64), lo, max(lo, hi))
    offs, w = _kernel(pos - base, interpolation)
    out = 0.0
    for k, off in enumerate(offs):
        idx = np.clip(base + off, 0, n - 1)
        shape = [1] * values.ndim
        shape[axis] = pos.size
        out = out + np.take(values, idx, axis=axis) * w[:, k].reshape(shape).astype(values.dtype)
    return out


class CycleTable:
    """Steady-cycle wrench samples of S shapes at flow nodes g_lo .. g_lo + G - 1, and their fine grid.

    Coarse: ``values (S, G, J, 6)``, sample j at phase (j - 1) * phase_step[s]. Fine: ``fine (S, Gf,
    Jf, 6)``, fine flow k at node position g_lo + k / Rf, fine phase m at coarse sample 1 + m / Rp.
    """

    def __init__(self, shapes: Shapes, source: CycleSource, settings: TabulationSettings):
        self.shapes = shapes
        self.source = source
        self.settings = settings
        self.step = float(settings.flow_step_mps)
        self.phase_step = source.phase_step(shapes)
        self.n_samples = source.n_samples(shapes)
        self.n_j = int(self.n_samples.max())
        self.rp = max(1, int(math.ceil(settings.fine_phase_samples * float(self.phase_step.max()) - 1e-9)))
        self.rf = int(settings.fine_flow_factor)
        self.n_ch = source.n_channels
        self.g_lo = 0
        self.values = np.zeros((len(shapes), 0, self.n_j, self.n_ch))
        self.done = np.zeros((len(shapes), 0), bool)
        #: float32: it is read four times per leg and tick in every fixed-point iteration
        self.fine = np.zeros((len(shapes), 0, (self.n_j - 3) * self.rp + 1, self.n_ch), np.float32)
        self.model_time_s = 0.0

    @property
    def n_nodes(self) -> int:
        """Nodes in the current grid."""
        return self.values.shape[1]

    def ensure(self, lo: np.ndarray, hi: np.ndarray) -> bool:
        """Make nodes lo[s] .. hi[s] (integers, inclusive; lo > hi: none) of every shape s available.

        Returns True if any node was new.
        """
        need = lo <= hi
        if not need.any():
            return False
        want_lo, want_hi = int(lo[need].min()), int(hi[need].max())
        g_hi_now = self.g_lo + self.n_nodes - 1
        if not self.n_nodes or want_lo < self.g_lo or want_hi > g_hi_now:
            # grow the grid with a node of margin on the growing side (fewer re-allocations)
            g_lo = want_lo - 1 if not self.n_nodes or want_lo < self.g_lo else self.g_lo
            g_hi = want_hi + 1 if not self.n_nodes or want_hi > g_hi_now else g_hi_now
            size = g_hi - g_lo + 1
            values = np.zeros((len(self.shapes), size, self.n_j, self.n_ch))
            done = np.zeros((len(self.shapes), size), bool)
            fine = np.zeros((len(self.shapes), (size - 1) * self.rf + 1, self.fine.shape[2], self.n_ch), np.float32)
            if self.n_nodes:
                a = self.g_lo - g_lo
                values[:, a:a + self.n_nodes] = self.values
                done[:, a:a + self.n_nodes] = self.done
                fine[:, a * self.rf:a * self.rf + self.fine.shape[1]] = self.fine
            self.values, self.done, self.fine, self.g_lo = values, done, fine, g_lo
        nodes = np.arange(self.n_nodes) + self.g_lo
        want = (nodes[None, :] >= lo[:, None]) & (nodes[None, :] <= hi[:, None]) & ~self.done
        s_idx, g_idx = np.nonzero(want)
        if s_idx.size == 0:
            return False
        t0 = time.perf_counter()
        out = self.source.cycles(self.shapes, s_idx, (g_idx + self.g_lo) * self.step, self.n_j)
        self.model_time_s += time.perf_counter() - t0
        self.values[s_idx, g_idx] = out
        self.done[s_idx, g_idx] = True
        self._refine(np.unique(s_idx), int(g_idx.min()), int(g_idx.max()))
        return True

    def _refine(self, rows: np.ndarray, i_lo: int, i_hi: int) -> None:
        """Fine grid of some shapes around new nodes i_lo .. i_hi (grid indices), from the coarse samples.

        Separable Catmull-Rom (or linear): a node changes the fine values up to two intervals away.
        Fine values between nodes that are not made yet are meaningless; reads never reach them.
        """
        interp = self.settings.interpolation
        n = self.n_nodes
        f_lo, f_hi = max(0, i_lo - 2), min(n - 1, i_hi + 2)           # fine values to redo, node units
        c_lo, c_hi = max(0, f_lo - 1), min(n - 1, f_hi + 2)           # coarse nodes they depend on
        pos_j = 1.0 + np.arange((self.n_j - 3) * self.rp + 1) / self.rp
        by_phase = _resample(self.values[rows, c_lo:c_hi + 1].astype(np.float32), 2, pos_j, interp)
        k = np.arange(f_lo * self.rf, f_hi * self.rf + 1)
        self.fine[rows[:, None], k[None, :]] = _resample(by_phase, 1, k / self.rf - c_lo, interp)

    def read(self, s_of_leg: np.ndarray, m0: np.ndarray, tp: np.ndarray, flow: np.ndarray) -> np.ndarray:
        """Bilinear read (N, T, channels) at fine phase positions (m0 + tp) and flows ``flow`` (N, T).

        In float32 (the table's precision, 1e-7 relative): it is the rollout's inner loop.
        """
        n_gf, n_jf = self.fine.shape[1], self.fine.shape[2]
        vf = (flow / self.step - self.g_lo) * self.rf
        k0 = np.clip(np.floor(vf).astype(np.int64), 0, n_gf - 2)
        tf = (vf - k0).astype(np.float32)[..., None]
        flat = self.fine.reshape(-1, self.n_ch)
        base = (s_of_leg[:, None] * n_gf + k0) * n_jf + m0
        tpc = tp.astype(np.float32)[..., None]
        out = np.take(flat, base, axis=0) * ((1 - tpc) * (1 - tf))
        out += np.take(flat, base + 1, axis=0) * (tpc * (1 - tf))
        out += np.take(flat, base + n_jf, axis=0) * ((1 - tpc) * tf)
        out += np.take(flat, base + n_jf + 1, axis=0) * (tpc * tf)
        return out


class TabulatedLegModel(LegForceModel):
    """A leg force model served from per-shape cycle tables for one gait batch (see the module docstring).

    Motions other than the batch's (and every motion when tabulation is off) go to the wrapped
    model unchanged, so the wrapper is a faithful :class:`LegForceModel` everywhere. ``flow_kernel``
    (from :meth:`CycleSource.flow_kernel`) may be passed in to probe the model once per run.
    """

    def __init__(self, inner: LegForceModel, gaits: GaitBatch, settings: TabulationSettings | None = None,
                 *, sim_dt_s: float, flow_kernel: np.ndarray | None = None):
        self.inner = inner
        self.gaits = gaits
        self.settings = settings or TabulationSettings()
        self.name = getattr(inner, "name", "model")
        self.sim_dt_s = float(sim_dt_s)
        # legs (gait-major, b * 4 + leg, as GaitBatch.leg_motion orders them) -> distinct shapes
        keys = np.stack([gaits.theta_h_min_deg.ravel(), gaits.theta_k_max_deg.ravel(),
                         np.repeat(gaits.frequency_hz, 4)], axis=-1)
        uniq, inverse = np.unique(keys, axis=0, return_inverse=True)
        self.leg_shape = inverse.ravel()
        self.shapes = Shapes(uniq[:, 0], uniq[:, 1], uniq[:, 2], gaits.theta_h_max_deg, gaits.theta_k_min_deg,
                             gaits.phi_rad)
        st = self.settings
        self.source = CycleSource(inner, sim_dt_s=sim_dt_s, phase_samples=st.phase_samples, warmup_s=st.warmup_s,
                                  history_order=st.history_order if st.flow_memory else 0,
                                  history_phase_stride=st.history_phase_stride, history_step_mps=st.history_step_mps)
        self.table = CycleTable(self.shapes, self.source, self.settings)
        self._flow_kernel = flow_kernel
        self.interp_time_s = 0.0
        self.startup_time_s = 0.0
        self.direct_calls = 0

    @property
    def tabulating(self) -> bool:
        """Whether this wrapper uses its tables (mode and model kind)."""
        mode = self.settings.mode
        return mode == "always" or (mode == "auto" and not callable(getattr(self.inner, "flow_provider", None)))

    @property
    def flow_kernel(self) -> np.ndarray:
        """Flow-memory weights (lag 0 first) of a model that is not a window net, probed on first use.

        [1] when switched off and for window nets (their flow history is tabulated instead).
        """
        if not self.settings.flow_memory or self.source.kind == "window":
            return np.ones(1)
        if self._flow_kernel is None:
            self._flow_kernel = self.source.flow_kernel()
        return np.asarray(self._flow_kernel, float)

    # -- LegForceModel ---------------------------------------------------------------------------
    def wrench(self, motion: LegMotion) -> np.ndarray:
        """The tabulated wrench for the batch's motion, the wrapped model's for any other."""
        if self.tabulating and self.is_batch_motion(motion):
            return self.flow_provider(motion)(motion.flow_speed_mps)
        self.direct_calls += 1
        return self.inner.wrench(motion)

    def flow_provider(self, motion: LegMotion) -> Callable[[np.ndarray], np.ndarray]:
        """``flow (4B, T) -> wrench (4B, T, 6)`` for the batch's motion (the simulator's hook)."""
        if not (self.tabulating and self.is_batch_motion(motion)):
            fast = getattr(self.inner, "flow_provider", None)
            if callable(fast):
                return fast(motion)
            from dataclasses import replace

            def direct(flow):
                self.direct_calls += 1
                return self.inner.wrench(replace(motion, flow_speed_mps=flow))

            return direct
        return self._provider(motion)

    def is_batch_motion(self, motion: LegMotion) -> bool:
        """Whether ``motion`` is this batch's legs on ticks 0, dt, 2 dt, ... (the simulator's motion)."""
        n, t = motion.shape
        if n != 4 * len(self.gaits) or t < 1:
            return False
        ref = self.gaits.leg_motion(np.arange(t) * motion.dt_s)
        return bool(np.array_equal(ref.theta_h_deg, motion.theta_h_deg)
                    and np.array_equal(ref.theta_k_deg, motion.theta_k_deg))

    def describe(self) -> dict:
        """The wrapped model's record plus the tabulation settings."""
        return {**self.inner.describe(), "tabulation": asdict(self.settings), "tabulation_kind": self.source.kind}

    def stats(self) -> dict:
        """Work done so far: model calls, (shape, node) pairs, windows or ticks predicted, seconds."""
        return {"kind": self.source.kind, "shapes": len(self.shapes), "model_calls": self.source.calls,
                "pairs": self.source.pairs, "windows": self.source.windows, "nodes": self.table.n_nodes,
                "model_time_s": self.table.model_time_s, "startup_time_s": self.startup_time_s,
                "interp_time_s": self.interp_time_s, "direct_calls": self.direct_calls}

    # -- the interpolating provider -------------------------------------------------------------
    def _provider(self, motion: LegMotion) -> Callable[..., np.ndarray]:
        g = self.gaits
        table = self.table
        n_ticks = motion.shape[1]
        t = np.arange(n_ticks) * motion.dt_s
        phase = np.mod(np.repeat(g.frequency_hz, 4)[:, None] * t[None, :]
                       + g.alpha_rad.ravel()[:, None] / (2 * np.pi), 1.0)              # cycles in [0, 1)
        s_of_leg = self.leg_shape
        uf = phase / table.phase_step[s_of_leg, None] * table.rp                        # fine phase position
        m0 = np.floor(uf).astype(np.int64)
        tp = uf - m0
        offs, _ = _kernel(np.zeros(1), self.settings.interpolation)
        n_shapes = len(self.shapes)
        head = _Head(self, motion) if self.settings.startup_correction else None
        if self.source.history_order:
            filters = self.source.history_filters()                         # level, then history terms

            def levels(flow, lo, hi):
                coef = [_filter_flow(flow, taps, lo, hi) for taps in filters]
                return coef[0], coef[1:]
        else:
            kernel = self.flow_kernel

            def levels(flow, lo, hi):
                return _filter_flow(flow, kernel, lo, hi), []

        def provider(flow: np.ndarray, legs: np.ndarray | None = None, lo: int = 0,
                     hi: int | None = None) -> np.ndarray:
            """Wrenches (legs, hi - lo, 6) of some legs (rows; all by default) over ticks lo .. hi - 1.

            ``flow`` is the whole (4B, T) history (the flow-history terms look back before ``lo``).
            A leg's numbers depend on its own flow only, never on which other legs are asked.
            """
            t_start = time.perf_counter()
            t_model, t_head = table.model_time_s, self.startup_time_s
            flow = np.asarray(flow, float)
            rows = np.arange(flow.shape[0]) if legs is None else np.asarray(legs, np.int64)
            hi = flow.shape[1] if hi is None else int(hi)
            # the start-up ticks are corrected from the tabulated wrench of ticks 0 .. m - 1
            start = 0 if head is not None and lo < head.m else int(lo)
            end = max(hi, head.m) if head is not None and start == 0 else hi
            sub = flow[rows]
            level, terms = levels(sub, start, end)
            shape_of = s_of_leg[rows]
            g0 = np.floor(level / table.step).astype(np.int64)
            # nodes each shape needs: its legs' lowest and highest flows plus the kernel's reach
            lo_n = np.full(n_shapes, np.iinfo(np.int64).max)
            hi_n = np.full(n_shapes, np.iinfo(np.int64).min)
            np.minimum.at(lo_n, shape_of, g0.min(axis=1) + offs[0])
            np.maximum.at(hi_n, shape_of, g0.max(axis=1) + offs[-1])
            table.ensure(lo_n, hi_n)
            read = table.read(shape_of, m0[rows, start:end], tp[rows, start:end], level)
            out = read[..., :6].astype(float)
            for k, a in enumerate(terms):
                out += a[..., None] * read[..., 6 * (k + 1):6 * (k + 2)]
            if head is not None and start == 0:
                head.apply(rows, sub, out)
            self.interp_time_s += (time.perf_counter() - t_start - (table.model_time_s - t_model)
                                   - (self.startup_time_s - t_head))
            return out[:, lo - start:hi - start]

        provider.partial = True  # the simulator may ask for some legs over some ticks (leg_wrench_provider)
        return provider


class _Head:
    """The first ticks of a tabulated rollout, straight from the model (see ``startup_correction``).

    Within the model's memory of the start a direct rollout sees a padded history (a window net
    repeats the first tick, a filter starts at rest), which the periodic table cannot know. These
    few ticks of the legs asked for are predicted directly, at the actual flow, whenever one of
    them moved more than ``startup_tol_mps`` since the last time; in between, the table's change
    from then to now is added to the cached prediction. The simulator asks for the gaits still
    iterating only.
    """

    def __init__(self, owner: "TabulatedLegModel", motion: LegMotion):
        from dataclasses import replace

        self.owner = owner
        self.m = min(motion.shape[1], owner.source.memory_ticks)
        self.motion = replace(motion, **{k: getattr(motion, k)[:, :self.m] for k in (
            "theta_h_deg", "theta_k_deg", "omega_h_dps", "omega_k_dps", "flow_speed_mps")},
            **{k: (None if getattr(motion, k) is None else getattr(motion, k)[:, :self.m])
               for k in ("alpha_h_dps2", "alpha_k_dps2")})
        self.tol = owner.settings.startup_tol_mps
        n = motion.shape[0]
        self.flow = np.full((n, self.m), np.inf)
        self.direct = np.zeros((n, self.m, 6))
        self.tab = np.zeros((n, self.m, 6))
        self.evaluations = 0

    def apply(self, rows: np.ndarray, flow: np.ndarray, out: np.ndarray) -> None:
        """Replace the first ticks of ``out`` (legs ``rows``: the tabulated wrench at ``flow``, from tick 0) in place."""
        from dataclasses import replace

        m = self.m
        now = flow[:, :m]
        # per gait (its four legs are rows 4 g .. 4 g + 3): one of its legs that moved makes all four new, whatever
        # the other gaits asked for did, so a gait's numbers do not depend on its batch (simulator workers)
        gait = rows // 4
        still = np.abs(now - self.flow[rows]).max(axis=1, initial=0.0) <= self.tol
        moved_gait = np.zeros(int(gait.max(initial=0)) + 1, bool)
        np.logical_or.at(moved_gait, gait, ~still)
        moved = moved_gait[gait]
        if moved.any():
            t0 = time.perf_counter()
            redo = rows[moved]
            part = replace(self.motion, flow_speed_mps=np.ascontiguousarray(now[moved]),
                           **{k: getattr(self.motion, k)[redo] for k in (
                               "theta_h_deg", "theta_k_deg", "omega_h_dps", "omega_k_dps")},
                           **{k: (None if getattr(self.motion, k) is None else getattr(self.motion, k)[redo])
                              for k in ("alpha_h_dps2", "alpha_k_dps2")})
            self.direct[redo] = np.asarray(self.owner.inner.wrench(part), float)
            self.owner.source.windows += redo.size * m
            self.owner.startup_time_s += time.perf_counter() - t0
            self.flow[redo] = now[moved]
            self.tab[redo] = out[moved, :m]
            self.evaluations += 1
        out[:, :m] = self.direct[rows] + (out[:, :m] - self.tab[rows])


def _filter_flow(flow: np.ndarray, kernel: np.ndarray, lo: int = 0, hi: int | None = None) -> np.ndarray:
    """Causal FIR filter of each row's flow history with weights ``kernel`` (lag 0 first); rest before t = 0.

    Ticks ``lo .. hi - 1`` of the filtered history (all by default): the same numbers as filtering
    the whole history and slicing.
    """
    n = flow.shape[1]
    hi = n if hi is None else hi
    if kernel.size <= 1:
        return flow[:, lo:hi]
    k = kernel.size
    if lo >= k - 1:
        seg = flow[:, lo - (k - 1):hi]
    else:
        seg = np.concatenate([np.repeat(flow[:, :1], k - 1 - lo, axis=1), flow[:, :hi]], axis=1)
    width = hi - lo
    out = np.zeros((flow.shape[0], width))
    for lag, w in enumerate(kernel):
        if w != 0.0:
            out += w * seg[:, k - 1 - lag:k - 1 - lag + width]
    return out
