"""The fitting problem: a campaign, the diagnosed model and how configurations are fitted and judged.

:class:`Problem` evaluates a :class:`~workbench.diagnose.chain.Configuration` on every batch
(or on a smaller *search* subsample of training runs, for the nonlinear searches), reduces it
to block sums and fits it. Channel weights are fixed once, from the diagnosed model's own
training residual, so every configuration is judged on the same scale.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable

import numpy as np

from workbench.diagnose import lsq
from workbench.diagnose.chain import Configuration, Lowpass, build_design, compare_filter
from workbench.diagnose.data import Campaign, RunSet, crossfit_folds, make_blocks, make_runset
from workbench.hydro.kinematics import DEFAULT_GEOMETRY
from workbench.hydro.motion import LegMotion


@dataclass(frozen=True)
class FitSettings:
    """Fit knobs (``pipelines/diagnose.yaml`` section ``fit``)."""

    #: training runs used by the nonlinear searches (a deterministic subsample), and their tick stride
    search_runs: int = 40
    search_stride: int = 4
    #: Newey-West lags (in blocks) of the robust covariances and tests
    hac_lags: int = 2
    #: fixed-point passes when crosstalk reads coefficients of the force terms
    passes: int = 3
    #: further passes, with damped steps, when the passes swing back and forth (a 2-cycle) instead of settling
    damped_passes: int = 8
    #: further calls of those passes for the fits claims are judged and reported on, until they settle
    settle_rounds: int = 4
    #: searches over a servo lag lag the model's output instead of its input (first-order exact;
    #: the final refinement uses the model itself): "auto" when the model costs more than
    #: ``expensive_us_per_tick`` (a windowed LSTM), or true / false
    surrogate_search: str | bool = "auto"
    expensive_us_per_tick: float = 40.0


def us_per_tick(model, probe: LegMotion, runs: int = 3) -> float:
    """The model's cost in microseconds per tick on ``probe``: the fastest of ``runs`` runs (load adds, never removes)."""
    import time

    best = np.inf
    for _ in range(runs):
        t0 = time.perf_counter()
        model.wrench(probe)
        best = min(best, time.perf_counter() - t0)
    return 1e6 * best / max(probe.theta_h_deg.size, 1)


def expensive(model, timed: Callable[[], float], limit_us: float) -> tuple[bool, str]:
    """Whether searches over input effects should use the surrogate (``surrogate_search: auto``), and why.

    Decided by what the model is where it says, so that the same data give the same diagnosis on a busy
    machine and an idle one: a model's own ``expensive`` attribute (a plugin model may declare it); a
    window net (``seq_len`` > 1 recurrent steps for every tick it predicts: the FED-LSTM's 32); a model
    wrapping another (``base``: an augmented model) as its base. Only a model that says none of these is
    timed (``timed()``: microseconds a tick, called only then) against ``limit_us``. Measured (30 Nov 2026): the FED-LSTM cost 37-60 us a tick on this
    two-core machine against the 40 us limit, so the timed rule flipped with the load between cases of
    one battery, and with it the searches (the exact model in every evaluation: 598 s for one case, 16-54
    s for its neighbours with the surrogate) and the selection path (``follow_lookahead`` is off with the
    surrogate).
    """
    seen = model
    for _ in range(8):
        own = getattr(seen, "expensive", None)
        if isinstance(own, bool):
            return own, f"{type(seen).__name__}.expensive is {own}"
        window = getattr(seen, "seq_len", None)
        if isinstance(window, int) and window > 1:
            return True, f"a window net, {window} steps for every tick it predicts"
        inner = getattr(seen, "base", None)
        if inner is None or inner is seen or not hasattr(inner, "wrench"):
            break
        seen = inner
    us = timed()
    return us > limit_us, f"timed: {us:.0f} us a tick against fit.expensive_us_per_tick {limit_us:g}"


class Problem:
    """A campaign and a model, with cached blocks and search subsample."""

    def __init__(self, campaign: Campaign, model, lowpass: Lowpass | None = None,
                 settings: FitSettings | None = None, geometry=DEFAULT_GEOMETRY):
        self.campaign = campaign
        self.model = model
        self.lowpass = lowpass
        self.settings = settings or FitSettings()
        self.geometry = geometry
        ds = campaign.settings
        self._blocks = {id(rs): make_blocks(rs, ds.tick_stride, ds.block_s) for rs in campaign.sets}
        self.search_sets = self._make_search_sets()
        self._search_blocks = {id(rs): make_blocks(rs, self.settings.search_stride, ds.block_s)
                               for rs in self.search_sets}
        self.weights = np.ones(6)
        # the model's output, kinematics and the last force-stage stack per batch (a search over a
        # filter, sensor or per-run parameter, and the fixed-point passes, reuse them)
        self._caches: dict[int, dict] = {id(rs): {} for rs in [*self.search_sets, *campaign.sets]}
        #: per effect, why its last final search did not converge (``selection_finish.refine``; absent: it did)
        self.search_notes: dict[str, str] = {}
        m = campaign.train_sets[0].motion
        probe = LegMotion(m.dt_s, *(x[:2] for x in (m.theta_h_deg, m.theta_k_deg, m.omega_h_dps, m.omega_k_dps,
                                                     m.flow_speed_mps, m.alpha_h_dps2, m.alpha_k_dps2)))
        base = self.fit(Configuration(), sets="train")
        mode = self.settings.surrogate_search
        #: why the searches do or do not use the surrogate (``fit.surrogate_search``)
        self.surrogate_reason = ""
        if mode == "auto":
            self.surrogate_search, self.surrogate_reason = expensive(
                self.model, lambda: us_per_tick(self.model, probe), self.settings.expensive_us_per_tick)
        else:
            self.surrogate_search = bool(mode)
        sse_c = base.sse_block_c.sum(axis=0)
        n = base_n = self._ticks(sets="train")
        var = sse_c / max(n, 1)
        floor = max(var.max(), 1e-300) * 1e-10
        self.weights = 1.0 / np.maximum(var, floor)
        del base_n

    # ---------------------------------------------------------------- batches
    def _make_search_sets(self) -> list[RunSet]:
        train = [i for i, h in enumerate(self.campaign.heldout) if not h]
        n = self.settings.search_runs
        if n and len(train) > n:
            pick = np.linspace(0, len(train) - 1, n).round().astype(int)
            train = [train[i] for i in sorted(set(pick))]
        runs = self.campaign.runs
        ds = self.campaign.settings
        train = sorted(train, key=lambda i: len(runs[i].time_s))
        size = max(1, ds.chunk_runs)
        return [make_runset([runs[i] for i in train[j:j + size]], train[j:j + size], self.campaign.dt_s, ds, False,
                            self.campaign.offsets, self.campaign.flow_offsets)
                for j in range(0, len(train), size)]

    def sets(self, which: str) -> list[tuple[RunSet, object]]:
        """Batches with their blocks: ``all``, ``train``, ``heldout`` or ``search``."""
        if which == "search":
            return [(rs, self._search_blocks[id(rs)]) for rs in self.search_sets]
        c = self.campaign
        chosen = {"all": c.sets, "train": c.train_sets, "heldout": c.heldout_sets}[which]
        return [(rs, self._blocks[id(rs)]) for rs in chosen]

    def _ticks(self, sets: str) -> int:
        return int(sum((b.ticks >= 0).sum() for _, b in self.sets(sets)))

    def context(self, rs: RunSet, config: Configuration):
        """The batch's cached effect context under ``config``'s input effects (None when not cacheable)."""
        from workbench.diagnose.chain import _key

        cache = self._caches.get(id(rs))
        if cache is None:
            return None
        key = ("ctx", _key(config.stage("input")))
        if key not in cache:
            self.design(rs, Configuration(list(config.stage("input"))), {}, names=[])
        return cache.get(key)

    # ------------------------------------------------------------------- fits
    def design(self, rs: RunSet, config: Configuration, coefs: dict | None = None, names=None,
               surrogate: bool = False):
        """The configuration on one batch (``surrogate``: servo lags on the model's output, for searches)."""
        d = build_design(self.model, rs, config, coefs, self.lowpass, self.geometry,
                         only=None if names is None else set(names), cache=self._caches.get(id(rs)),
                         surrogate=surrogate)
        d.compare = compare_filter(config, rs.dt_s)
        return d

    def grams(self, config: Configuration, coefs: dict | None = None, names: list[str] | None = None,
              sets: str = "all", surrogate: bool | None = None, shift: dict | None = None) -> lsq.Grams:
        """Block sums of ``config`` (columns restricted to ``names`` when given).

        ``surrogate``: input effects through :class:`~workbench.diagnose.chain.SurrogateContext`
        when the model is expensive (None: for the search subsample only). ``shift``: per batch
        (by ``id``), an array added to the reading (taken off the design's base), for a search's
        stand-in criterion (:meth:`~workbench.diagnose.effects.base.Effect.search_reading`).
        """
        parts = []
        surrogate = (sets == "search" if surrogate is None else surrogate) and getattr(self, "surrogate_search", False)
        for rs, blocks in self.sets(sets):
            d = self.design(rs, config, coefs, names, surrogate=surrogate)
            if shift is not None:
                d.base = d.base - shift[id(rs)]
            parts.append(lsq.accumulate(d, rs, blocks, names if names is not None else d.names))
        gr = lsq.concat(parts)
        gr.prior = self.priors(config, gr.names)
        return gr

    @staticmethod
    def priors(config: Configuration, names: list[str]) -> dict | None:
        """Gaussian priors the effects of ``config`` put on the linear parameters in ``names`` (a blockage's Maskell factor)."""
        prior = {f"{a.name}.{k}": v for a in config.actives for k, v in (getattr(a.effect, "priors", dict)() or {}).items()}
        return {k: v for k, v in prior.items() if k in names} or None

    def block_folds(self, grams: lsq.Grams, folds: int) -> np.ndarray:
        """Per block of ``grams``, its run's fold of a cross-fitted test (:func:`~workbench.diagnose.data.crossfit_folds`)."""
        cache = self.__dict__.setdefault("_folds", {})
        if folds not in cache:
            c = self.campaign
            cache[folds] = crossfit_folds(c.runs, c.heldout, folds, c.settings.split_decimals)
        return cache[folds][grams.run]

    def fit(self, config: Configuration, coefs: dict | None = None, names: list[str] | None = None,
            sets: str = "all", fixed: dict | None = None, surrogate: bool | None = None) -> lsq.Fit:
        """Fit ``config``; repeats while sensor columns read the prediction, which the force coefficients change."""
        coefs = dict(coefs or {})
        passes = self.settings.passes if _reads_prediction(config) else 1
        # the coefficients of effects that read the prediction follow the others: they do not set the pace
        readers = tuple(f"{a.name}." for a in config.actives if a.effect.reads_prediction)
        result, step, last = None, 1.0, None
        k = 0
        while True:
            gr = self.grams(config, coefs, names, sets, surrogate)
            result = lsq.fit(gr, self.weights, self.settings.hac_lags, fixed)
            new = result.coefs()
            change = max((abs(new[n] - coefs.get(n, 0.0)) / (abs(new[n]) + 1e-12) for n in new
                          if not n.startswith(readers)), default=0.0)
            move = {n: (v - coefs.get(n, 0.0)) / (abs(v) + 1e-12) for n, v in new.items()}
            k += 1
            if change < lsq.FixedPoint.RELATIVE:
                break
            if step == 1.0 and last is not None and _reverses(move, last):
                # the passes swing back and forth (a crosstalk's guard reads residuals the force
                # coefficients move: measured a 2-cycle whose held-out error alternated 0.1738 / 0.1723
                # and whose training error rose above the fit without the last effect): damped steps,
                # which make a swing of factor -1 contract at once, until the change settles
                step = 0.5
            if k >= (passes if step == 1.0 else passes + self.settings.damped_passes):
                break
            coefs.update({n: coefs.get(n, 0.0) + step * (v - coefs.get(n, 0.0)) for n, v in new.items()})
            last = move
        if passes > 1:
            result.fixed_point = _fixed_point(result, coefs, k, change)
        result.grams = gr  # type: ignore[attr-defined]
        return result


def _fixed_point(result: lsq.Fit, coefs: dict, passes: int, change: float) -> lsq.FixedPoint:
    """How far the last pass moved the coefficients from the ones its columns were built with, in standard errors."""
    se = result.stderr()
    moves = {n: abs(v - coefs.get(n, 0.0)) / se[n] if se[n] > 0 else 0.0 for n, v in result.coefs().items()}
    worst = max(moves, key=moves.get, default="")
    step_se = float(moves.get(worst, 0.0))
    return lsq.FixedPoint(passes, float(change), step_se, worst,
                          bool(change < lsq.FixedPoint.RELATIVE or step_se < lsq.FixedPoint.STEP_SE))


def fit_settled(problem: Problem, config: Configuration, coefs: dict | None = None, names: list[str] | None = None,
                rounds: int | None = None) -> lsq.Fit:
    """:meth:`Problem.fit` continued from its own coefficients until its fixed point is reached (``rounds`` more calls at most).

    For the fits claims are judged and reported on (the final backward check, the final fit): one
    call's passes stop at ``fit.passes`` when they settle slowly, and a fit without an effect,
    started from the coefficients of the fit with it, then reads a training error above its fixed
    point's (measured 3001 against 2627), which favours keeping the effect. The fixed-point
    record counts the passes of every call.
    """
    rounds = problem.settings.settle_rounds if rounds is None else rounds
    f = problem.fit(config, coefs, names)
    if f.fixed_point is None:  # one linear solve: nothing to settle
        return f
    total = f.fixed_point.passes
    for _ in range(rounds):
        if f.fixed_point.settled:
            break
        f = problem.fit(config, f.coefs(), names)
        total += f.fixed_point.passes
    f.fixed_point = dataclasses.replace(f.fixed_point, passes=total)
    return f


def _reverses(move: dict, last: dict) -> bool:
    """Whether a pass's relative coefficient change points back against the previous one (cosine < -0.5)."""
    keys = [n for n in move if n in last]
    a, b = np.array([move[n] for n in keys]), np.array([last[n] for n in keys])
    den = float(np.linalg.norm(a) * np.linalg.norm(b))
    return den > 0 and float(a @ b) / den < -0.5


def _reads_prediction(config: Configuration) -> bool:
    has_force_cols = any(a.effect.linear_names() for a in config.stage("force"))
    return has_force_cols and any(a.effect.reads_prediction for a in config.actives)


def run_residuals(problem: Problem, config: Configuration, fit: lsq.Fit | None = None):
    """Every run's measured and predicted wrench under ``config`` fitted by ``fit`` (all ticks)."""
    from workbench.diagnose.evidence_base import RunResidual

    coefs = fit.coefs() if fit is not None else {}
    out = []
    for rs in problem.campaign.sets:
        d = problem.design(rs, config, coefs)
        local = None
        if d.local_names and fit is not None and fit.local:
            m = len(d.local_names)
            vals = np.array([fit.local.get(int(i), np.zeros(m)) for i in rs.index])
            local = {n: vals[:, j] for j, n in enumerate(d.local_names)}
        pred = d.predict(coefs, local)
        m = rs.motion
        for i in range(rs.shape[0]):
            v = rs.valid[i]
            out.append(RunResidual(
                run_id=rs.run_ids[i], index=int(rs.index[i]), heldout=rs.heldout, flow=float(rs.flow[i]),
                freq=float(rs.freq[i]), dt_s=rs.dt_s, time_s=rs.time_s[i, v], fit=rs.fit[i, v], rest=rs.rest[i, v],
                theta_h=m.theta_h_deg[i, v], theta_k=m.theta_k_deg[i, v], omega_h=m.omega_h_dps[i, v],
                omega_k=m.omega_k_dps[i, v], measured=rs.y[i, v], predicted=pred[i, v]))
    out.sort(key=lambda r: r.index)
    return out
