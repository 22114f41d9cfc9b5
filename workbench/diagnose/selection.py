"""Forward stepwise selection of effects, judged on held-out runs (a swappable object, after pysindy's optimizers).

Each step fits every remaining candidate on the training runs together with the effects
already chosen (nonlinear parameters by a grid search and a local refinement that wrap the
linear fit) and scores it on the held-out runs by the held-out log-likelihood gain: per block
and channel ``n/2 log(SSE_before / SSE_after)``, which weighs a quiet channel and a loud one
alike. An effect is claimed only when

* its mean block gain is positive by a one-sided t-test with a Newey-West variance over
  neighbouring blocks (autocorrelated residuals do not inflate the evidence), at level
  ``alpha`` divided by the number of candidates of the step (Bonferroni);
* it removes at least ``min_gain`` of the held-out MSE in the channel it helps most;
* it passes its structural checks (a flow tone must vanish at zero flow and scale with the
  flow sensitivity of the force; otherwise the peak is someone else's).

Per-run nuisance columns (a tone's phase) are fitted on held-out runs too; their gain is
measured against the same fit at off-peak frequencies (what fitting noise would gain).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import product

import numpy as np
from scipy import optimize, stats

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose import lsq
from workbench.diagnose.chain import Active, Configuration
from workbench.diagnose.effects.base import Effect, EffectLibrary


@dataclass(frozen=True)
class SelectionSettings:
    """Selection knobs (``pipelines/diagnose.yaml`` section ``selection``)."""

    alpha: float = 0.01
    min_gain: float = 0.02
    max_effects: int = 8
    #: entries of crosstalk/drift kept when significant at this level (Bonferroni over entries)
    prune_alpha: float = 0.001
    #: a runner-up reaching this share of the winner's held-out gain is reported as an alternative
    ambiguity_ratio: float = 0.7
    refine: bool = True
    #: half-width of the tone-frequency search around a residual peak (Hz)
    tone_window_hz: float = 0.12
    #: Nelder-Mead evaluations per nonlinear parameter in refinements
    refine_evals: int = 12
    #: tone candidates tried per step (the strongest residual lines)
    max_peaks: int = 2
    #: half-width (log units) of a warm-started 1-D search around the last optimum
    warm_window: float = 0.7
    #: also try linear effects two at a time (each may hide the other), claimed when the pair's
    #: held-out gain is at least ``pair_margin`` times its better member's alone
    pairs: bool = True
    pair_margin: float = 1.5
    #: a fitted structural mode damped more than this is a delay in disguise, not a mount mode
    #: (mount and sting modes are lightly damped, zeta << 0.3)
    max_mode_zeta: float = 0.3
    #: a flow tone may leave at most this share of its line's excess power (above the floor)
    tone_line_left: float = 0.4
    #: a claim needs its 95 % interval clear of zero (z = 1.96) on at least one magnitude parameter
    interval_z: float = 1.96
    #: greedy paths followed besides the main one: a look-ahead effect (``Effect.lookahead``, a servo
    #: delay) acceptable at a step but passed over is accepted there and the selection goes on; the
    #: path with the better final held-out fit (significant at ``alpha``) wins. 0: greedy only
    lookahead_branches: int = 1
    #: re-search a chosen look-ahead effect's searched values (a servo's delay) each time another effect comes
    #: in, and go on selecting once the final refinement has moved them (an effect the held value hid)
    follow_lookahead: bool = True


@dataclass
class Candidate:
    """One candidate effect fitted in one step."""

    effect: Effect
    active: Active
    config: Configuration
    names: list[str]
    fit: lsq.Fit
    test: dict = field(default_factory=dict)
    gain_c: np.ndarray = field(default_factory=lambda: np.zeros(6))
    profile: dict | None = None
    ok: bool = False
    note: str = ""
    #: a second linear effect claimed together with this one (each may hide the other alone)
    partner: Effect | None = None
    #: fitted through the expensive model's surrogate (refitted with the model before a claim)
    surrogate: bool = False

    @property
    def label(self) -> str:
        """Name, with the searched values."""
        nl = ", ".join(f"{k}={v:.3g}" for k, v in self.active.nl.items())
        own = f"{self.effect.name}({nl})" if nl else self.effect.name
        return f"{own} + {self.partner.name}" if self.partner is not None else own

    @property
    def effects(self) -> list[Effect]:
        """The effect, and its partner if any."""
        return [self.effect] + ([self.partner] if self.partner is not None else [])


@dataclass
class Step:
    """An accepted effect with its test and the alternatives it beat."""

    candidate: Candidate
    mse_before: np.ndarray
    mse_after: np.ndarray
    table: list[dict]
    alternatives: list[str]
    #: effects the held-out data cannot tell apart from this one (winner vs runner-up not significant)
    ambiguous_with: list[str] = field(default_factory=list)


@dataclass
class SelectionResult:
    """The chosen configuration, its fit and the record of every step."""

    config: Configuration
    names: list[str]
    fit: lsq.Fit
    steps: list[Step]
    last_table: list[dict]


def block_llr(before: lsq.Fit, after: lsq.Fit, gr: lsq.Grams) -> np.ndarray:
    """Held-out log-likelihood gain per block: sum over channels of n/2 log(SSE_before / SSE_after)."""
    sb = np.maximum(before.sse_block_c, 1e-300)
    sa = np.maximum(after.sse_block_c, 1e-300)
    return 0.5 * gr.n[:, None] * np.log(sb / sa)


def judge(before: lsq.Fit, after: lsq.Fit, gr: lsq.Grams, hac_lags: int, correction: np.ndarray | None = None):
    """Held-out test of ``after`` against ``before``: t, p, llr and per-channel relative MSE reduction.

    ``correction``: per block, what the same per-run fit gains at off-peak variants, ``(k, nb)`` (or
    their mean, ``(nb,)``). The gain beyond their mean is tested; with ``k >= 3`` variants against
    their spread (:func:`_null_spread_test`), otherwise by the blocks' own scatter.
    """
    raw = block_llr(before, after, gr).sum(axis=1)
    nulls = None
    if correction is not None and np.ndim(correction) == 2:
        nulls, correction = np.asarray(correction), np.mean(correction, axis=0)
    llr = raw - correction if correction is not None else raw
    # blocks the candidate leaves untouched (a flow term at zero flow) carry no evidence either way
    touched = np.abs(raw) > 1e-9 * max(np.abs(raw).max(), 1e-300)
    if correction is not None:
        touched |= np.abs(correction) > 0
    h = gr.heldout & touched
    g = llr[h]
    n = len(g)
    sb = before.sse_block_c[gr.heldout].sum(axis=0)
    sa = after.sse_block_c[gr.heldout].sum(axis=0)
    gain_c = np.where(sb > 0, (sb - sa) / np.maximum(sb, 1e-300), 0.0)
    if correction is not None:
        # the per-run nuisance fit gains on noise too: count only what beats the off-peak fits
        # (a share in [0, 1]: with no held-out gain before the correction there is none after it; dividing by a
        # floor instead blew a positive remainder up to ~1e300)
        total = float(raw[h].sum())
        gain_c = gain_c * (min(1.0, max(0.0, float(g.sum())) / total) if total > 0 else 0.0)
    if n < 3:
        return {"t": 0.0, "p": 1.0, "llr": float(g.sum()), "n_blocks": n}, gain_c
    if nulls is not None and len(nulls) >= 3:
        return _null_spread_test(raw[h], nulls[:, h], gr.run[h]), gain_c
    mean = g.mean()
    d = g - mean
    run, order = gr.run[h], gr.order[h]
    srt = np.argsort(run.astype(np.int64) * 1_000_000 + order)
    d, run, order = d[srt], run[srt], order[srt]
    var = float(d @ d)
    for lag in range(1, hac_lags + 1):
        same = (run[lag:] == run[:-lag]) & (order[lag:] - order[:-lag] == lag)
        var += 2 * (1 - lag / (hac_lags + 1)) * float(d[lag:][same] @ d[:-lag][same])
    se = np.sqrt(max(var, 1e-300) / n / max(n - 1, 1))
    t = float(mean / se)
    return {"t": t, "p": float(stats.t.sf(t, df=max(n - 1, 1))), "llr": float(g.sum()), "n_blocks": n}, gain_c


def _null_spread_test(raw: np.ndarray, nulls: np.ndarray, run: np.ndarray) -> dict:
    """A per-run fit's gain against the same fit's gains at its ``k`` off-peak variants, run by run.

    Where nothing is there, the fit at the proposed value is one more draw of what the variants
    gain: in each run a per-run fit of a few columns gains about a scaled chi-square, so the
    ratio of the run's gain to the variants' mean is F-distributed (degrees of freedom from the
    variants' own spread, pooled over runs), and the runs' p-values combine by Fisher's method.
    A gain that differs from run to run (a tone carried by ``U dF/dU`` is 16 times stronger at
    twice the flow speed) then counts as evidence, not as scatter; runs where the variants gain
    what the fit gains (they cannot tell the value) carry none. ``t``: the normal quantile of p.
    """
    k = len(nulls)
    rows = []
    for r in np.unique(run):
        m = run == r
        x, per = float(raw[m].sum()), nulls[:, m].sum(axis=1)
        scale = 1e-9 * max(float(np.abs(raw[m]).sum() + np.abs(per).sum()), 1e-300)
        if np.ptp(per) > scale or abs(x - per.mean()) > scale:
            rows.append((x, per))
    rows = [(x, per) for x, per in rows if per.mean() > 0]
    llr = float(sum(x - per.mean() for x, per in rows))
    if not rows:
        return {"t": 0.0, "p": 1.0, "llr": llr, "n_blocks": int(len(raw))}
    # a chi-square of nu degrees of freedom has var / mean^2 = 2 / nu
    cv2 = float(np.mean([np.var(per, ddof=1) / per.mean() ** 2 for _, per in rows]))
    nu = float(np.clip(2.0 / max(cv2, 1e-6), 1.0, 200.0))
    logp = sum(float(stats.f.logsf(max(x, 0.0) / per.mean(), nu, k * nu)) for x, per in rows)
    p = float(stats.chi2.sf(-2.0 * logp, 2 * len(rows)))
    return {"t": float(stats.norm.isf(min(max(p, 1e-300), 1 - 1e-12))), "p": p, "llr": llr, "n_blocks": int(len(raw))}


@dataclass
class _Path:
    """A selection path: the configuration so far, its fit and record, and the look-ahead branches passed."""

    config: Configuration
    names: list[str]
    current: lsq.Fit
    coefs: dict
    steps: list
    table: list
    last_nl: dict
    rounds: int = 0
    branches: list = field(default_factory=list)

    def copy(self) -> "_Path":
        """An independent copy (fits are shared: they are not changed in place)."""
        return _Path(self.config.copy(), list(self.names), self.current, dict(self.coefs), list(self.steps),
                     list(self.table), {k: dict(v) for k, v in self.last_nl.items()}, self.rounds, [])


@dataclass
class _Branch:
    """A look-ahead effect acceptable at a step but passed over: the path before that step, and the candidate."""

    path: _Path
    forced: Candidate
    level: float


class StepwiseSelection:
    """Forward stepwise selection of effects on held-out runs."""

    def __init__(self, settings: SelectionSettings | None = None):
        self.settings = settings or SelectionSettings()

    # ------------------------------------------------------------------ search
    def search(self, problem, config: Configuration, coefs: dict, names: list[str], effect: Effect,
               grids: dict[str, tuple] | None = None, start: dict | None = None) -> tuple[dict, dict]:
        """Nonlinear parameters of ``effect`` minimising the training SSE (linear terms refitted each time)."""
        params = effect.search
        pnames = [p.name for p in params]
        w = problem.weights
        hac = problem.settings.hac_lags
        cache: dict[tuple, float] = {}

        def objective(values) -> float:
            key = tuple(round(float(v), 10) for v in values)
            if key not in cache:
                nl = dict(zip(pnames, key, strict=False))
                cfg = config.with_effect(Active(effect, nl))
                extra = [f"{effect.name}.{n}" for n in effect.linear_names()]
                gr = problem.grams(cfg, coefs, names + extra, sets="search")
                cache[key] = float(lsq.fit(gr, w, hac).sse_block.sum())
            return cache[key]

        if start is not None and grids is None:
            best = [start[p] for p in pnames]
        else:
            axes = [grids[p.name] if grids and p.name in grids else p.grid for p in params]
            points = list(product(*axes))
            vals = [objective(pt) for pt in points]
            best = list(points[int(np.argmin(vals))])
        profile = {"params": pnames, "points": [list(k) for k in cache], "sse": list(cache.values())}
        # local refinement in (log) coordinates, clipped to the bounds
        logs = [p.log for p in params]
        lo = np.array([np.log(p.bounds[0]) if p.log else p.bounds[0] for p in params])
        hi = np.array([np.log(p.bounds[1]) if p.log else p.bounds[1] for p in params])

        def to_x(v):
            return np.array([np.log(max(x, 1e-300)) if lg else x for x, lg in zip(v, logs, strict=False)])

        def from_x(x):
            x = np.clip(x, lo, hi)
            return [float(np.exp(v)) if lg else float(v) for v, lg in zip(x, logs, strict=False)]

        x0 = to_x(best)
        warm = start is not None and grids is None
        if len(params) == 1:
            step = 0.25 if logs[0] else max(0.02 * abs(x0[0]), 0.01)
            if warm:
                step = self.settings.warm_window if logs[0] else max(0.2 * abs(x0[0]), 0.05)
            if grids and pnames[0] in grids and len(grids[pnames[0]]) > 1:
                step = float(np.diff(grids[pnames[0]]).mean())
            res = optimize.minimize_scalar(lambda x: objective(from_x(np.array([x]))),
                                           bounds=(max(lo[0], x0[0] - step), min(hi[0], x0[0] + step)),
                                           method="bounded",
                                           options={"xatol": 0.005 if logs[0] else 5e-4,
                                                    "maxiter": self.settings.refine_evals})
            xbest = np.array([res.x])
        else:
            simplex = [x0] + [x0 + np.eye(len(x0))[i] * (0.3 if logs[i] else 0.1 * max(abs(x0[i]), 0.5))
                              for i in range(len(x0))]
            res = optimize.minimize(lambda x: objective(from_x(x)), x0, method="Nelder-Mead",
                                    options={"initial_simplex": np.array(simplex),
                                             "maxfev": self.settings.refine_evals * len(x0) * 2,
                                             "xatol": 1e-3, "fatol": 1e-9})
            xbest = res.x
        out = from_x(xbest)
        if objective(out) > objective(best):
            out = best
        profile = {"params": pnames, "points": [list(k) for k in cache], "sse": list(cache.values())}
        return effect.searched(dict(zip(pnames, out, strict=False)), problem, config, coefs, names), profile

    # ------------------------------------------------------------ candidates
    def _linear_candidates(self, problem, config, coefs, names, effects) -> list[Candidate]:
        """Every linear effect alone, and every pair (fitted from one set of block sums)."""
        if not effects:
            return []
        sup = config
        for e in effects:
            sup = sup.with_effect(Active(e, {}))
        extra = {e.name: [f"{e.name}.{n}" for n in e.linear_names()] for e in effects}
        all_names = names + [n for e in effects for n in extra[e.name]]
        gr = problem.grams(sup, coefs, all_names)
        out = []
        groups = [(e,) for e in effects]
        if self.settings.pairs:
            groups += [(a, b) for i, a in enumerate(effects) for b in effects[i + 1:]]
        for group in groups:
            nm = names + [n for e in group for n in extra[e.name]]
            sub = gr.subset(nm)
            f = lsq.fit(sub, problem.weights, problem.settings.hac_lags)
            f.grams = sub  # type: ignore[attr-defined]
            cfg = config
            for e in group:
                cfg = cfg.with_effect(Active(e, {}))
            out.append(Candidate(group[0], Active(group[0], {}), cfg, nm, f,
                                 partner=group[1] if len(group) > 1 else None))
        return out

    def _nonlinear_candidate(self, problem, config, coefs, names, effect, peak=None, start=None) -> Candidate:
        grids = None
        if effect.needs_peak:
            f0 = peak.frequency_hz
            hw = self.settings.tone_window_hz
            # the frequency proposed by the evidence is the effect's first searched parameter
            grids = {effect.search[0].name: tuple(np.round(np.linspace(f0 - hw, f0 + hw, 9), 4))}
            start = None
        nl, profile = self.search(problem, config, coefs, names, effect, grids, start=start)
        if getattr(problem, "surrogate_search", False) and effect.stage == "input":
            # an expensive model runs once per input value: values on a 2 % (log) or 0.005 grid
            # recur from step to step, and the model's output for them is still cached
            nl = {p.name: _snap(nl[p.name], p) for p in effect.search}
        act = Active(effect, nl)
        cfg = config.with_effect(act)
        nm = names + [f"{effect.name}.{n}" for n in effect.linear_names()]
        # an input effect with an expensive model is screened through the surrogate; only the
        # candidate about to be claimed is refitted with the model itself (select)
        sur = bool(getattr(problem, "surrogate_search", False) and effect.stage == "input")
        f = problem.fit(cfg, coefs, nm, surrogate=sur)
        return Candidate(effect, act, cfg, nm, f, profile=profile, surrogate=sur)

    def _null_correction(self, problem, cand: Candidate, coefs, current: lsq.Fit) -> np.ndarray | None:
        variants = cand.effect.null_variants(cand.active.nl)
        if not variants:
            return None
        gains = []
        for nl in variants:
            cfg = cand.config.with_effect(Active(cand.effect, nl))
            f = problem.fit(cfg, coefs, cand.names)
            gains.append(block_llr(current, f, f.grams).sum(axis=1))
        return np.array(gains)

    # ------------------------------------------------------------------ select
    def select(self, problem, library: EffectLibrary, peaks_of=None, plausible=None, progress=None) -> SelectionResult:
        """Run the forward selection.

        ``peaks_of(effect, config, fit)`` returns the narrowband residual peaks a ``needs_peak``
        effect is tried at under a configuration; ``plausible(candidate, current_config,
        current_fit)`` returns ``(ok, note)`` for structural checks. Each effect is configured on
        the campaign first (:meth:`~workbench.diagnose.effects.base.Effect.configure`).

        Look-ahead: an effect that changes what every other term sees (``Effect.lookahead``, a
        servo's delay) may be acceptable at a step and still lose it to a force effect that takes
        its misfit channel by channel; once that force effect is in, the delay's own gain is no
        longer significant and the greedy path never comes back. The path that accepts it at that
        step is then followed too, and wins when its final held-out fit beats the greedy one's
        by the held-out test at ``alpha``.
        """
        s = self.settings
        library = library.configured(lambda: self._sample(problem))
        start = _Path(Configuration(), [], problem.fit(Configuration(), names=[]), {}, [], [], {})
        more = (library, peaks_of, plausible, progress)
        main = self._forward(problem, library, start, peaks_of, plausible, progress)
        result = self._finish(problem, main, more)
        for branch in main.branches[: s.lookahead_branches]:
            if branch.forced.effect.name in result.config.names():
                continue
            path = self._force(problem, branch, plausible)
            if path is None:
                continue
            alt = self._finish(problem, self._forward(problem, library, path, peaks_of, plausible, progress), more)
            test, _ = judge(result.fit, alt.fit, alt.fit.grams, problem.settings.hac_lags)
            if test["llr"] > 0 and test["p"] < s.alpha:
                result = alt
        return result

    def _forward(self, problem, library, path: "_Path", peaks_of, plausible, progress) -> "_Path":
        """Greedy steps from ``path`` until no candidate is accepted; look-ahead effects passed over are recorded."""
        s = self.settings
        hac = problem.settings.hac_lags
        path = path.copy()
        while path.rounds < s.max_effects:
            path.rounds += 1
            config, names, current, coefs = path.config, path.names, path.current, path.coefs
            remaining = [e for e in library if e.name not in config.names()]
            cands = self._candidates(problem, config, coefs, names, remaining, current, peaks_of, path.last_nl,
                                     progress)
            if not cands:
                break
            cands, table, level = self._judge_all(problem, cands, coefs, current, config, plausible)
            path.table = table
            best = self._pick(problem, cands, table, coefs, current, config, level, plausible)
            if best is None:
                break
            mine = {e.name for e in best.effects}
            seen = {b.forced.effect.name for b in path.branches}
            for c in cands:
                if (c.ok and c is not best and c.partner is None and c.effect.lookahead
                        and c.effect.name not in mine | seen):
                    path.branches.append(_Branch(path.copy(), c, level))
            alternatives = [c.label for c in cands if c is not best and not {e.name for e in c.effects} & mine
                            and c.test["llr"] >= s.ambiguity_ratio * best.test["llr"] and c.test["llr"] > 0]
            ambiguous = self._ambiguous(best, cands, level, hac, s.alpha)
            self._accept(problem, path, best, table, alternatives, ambiguous)
            self._follow(problem, path, mine)
        return path

    def _following(self, problem) -> bool:
        """Whether chosen look-ahead effects are searched again as the model grows (not with an expensive model)."""
        return bool(self.settings.follow_lookahead) and not getattr(problem, "surrogate_search", False)

    def _follow(self, problem, path: "_Path", skip: set[str]) -> None:
        """Re-search the searched values of the chosen look-ahead effects with the others as they are now (in place).

        A delay found at an early step is biased by the misfit the force effects have not yet
        taken (a 60 ms dead time came in at step 1 as 31 ms): held there, the force effects that
        come in later fit around the wrong delay and take its remainder channel by channel (an
        added mass 1.7 times the truth's), and an effect the remainder hides is never found.
        Searched again after every step (from its last value, and its neighbours on the grid),
        the delay follows the model as it grows. Not for an expensive model (its searches go
        through a surrogate; the final refinement finishes its values).
        """
        if not self._following(problem):
            return
        for a in list(path.config.actives):
            if not (a.effect.lookahead and a.effect.search) or a.name in skip:
                continue
            rest = path.config.without(a.name)
            nl, _ = self.search(problem, rest, path.coefs, path.names, a.effect, grids=_around(a.effect, a.nl))
            if all(abs(nl[k] - a.nl.get(k, np.nan)) <= 1e-9 * max(abs(nl[k]), 1.0) for k in nl):
                continue
            path.config = rest.with_effect(Active(a.effect, nl))
            path.current = problem.fit(path.config, path.coefs, path.names)
            path.coefs = path.current.coefs()
            path.last_nl[a.name] = dict(nl)

    @staticmethod
    def _accept(problem, path: "_Path", best: Candidate, table, alternatives, ambiguous) -> None:
        """Take ``best`` into ``path`` (in place) and record its step."""
        before_c = _heldout_mse(path.current)
        path.config, path.names = best.config, best.names
        path.current = problem.fit(path.config, path.coefs, path.names)
        path.coefs = path.current.coefs()
        for e in best.effects:
            member = Candidate(e, Active(e, dict(best.active.nl) if e is best.effect else {}), best.config,
                               best.names, best.fit, best.test, best.gain_c, best.profile, True, best.note)
            path.steps.append(Step(member, before_c, _heldout_mse(path.current), table, alternatives,
                                   [n for n in ambiguous if n != e.name]))

    def _force(self, problem, branch: "_Branch", plausible) -> "_Path | None":
        """The branch's path with its passed-over effect accepted (judged with the model itself; None if it fails)."""
        path = branch.path.copy()
        c = branch.forced
        if c.surrogate:
            c.fit = problem.fit(c.config, path.coefs, c.names, surrogate=False)
            c.surrogate = False
            self._assess(problem, c, path.coefs, path.current, path.config, branch.level, plausible)
            if not c.ok:
                return None
        self._accept(problem, path, c, path.table, [], [])
        return path

    def _finish(self, problem, path: "_Path", more: tuple | None = None) -> SelectionResult:
        """Refine the searched parameters jointly, then drop effects that no longer earn their place.

        ``more`` (library, peaks_of, plausible, progress): when the refinement has moved a
        look-ahead effect's values (a delay), the selection goes on from the refined configuration
        (an effect the held delay's remainder hid, such as a drift, may now be significant), and
        the new configuration is refined again.
        """
        config, names, current = path.config, path.names, path.current
        steps, table = list(path.steps), path.table
        if self.settings.refine and any(a.effect.search for a in config.actives):
            before = config.nl_values()
            config, current = self._refine(problem, config, path.coefs, names, current)
            if self._following(problem):
                config, names, current, steps, table = self._drop_refused(problem, config, names, current, steps, table)
            moved = any(a.effect.lookahead and any(abs(v - before.get(f"{a.name}.{k}", np.nan)) > 1e-9
                                                   for k, v in a.nl.items()) for a in config.actives)
            if more is not None and moved and self._following(problem):
                # the selection goes on from the refined values, for at most ``FOLLOW_ROUNDS`` more rounds
                go = _Path(config, list(names), current, current.coefs(), steps, table,
                           {a.name: dict(a.nl) for a in config.actives},
                           min(path.rounds, self.settings.max_effects - FOLLOW_ROUNDS))
                go = self._forward(problem, more[0], go, *more[1:])
                if len(go.config.actives) > len(config.actives):
                    config, names, current, steps, table = go.config, go.names, go.current, go.steps, go.table
                    config, current = self._refine(problem, config, current.coefs(), names, current)
                    config, names, current, steps, table = self._drop_refused(problem, config, names, current, steps, table)
        config, names, current, steps = self._backward_check(problem, config, names, current, steps)
        return SelectionResult(config, names, current, steps, table)

    def _drop_refused(self, problem, config, names, current, steps, table):
        """Drop effects whose refined searched values are refused or implausible, refining the rest each time.

        A candidate is judged with the values of its step; the final refinement moves them (a mode
        taken at zeta 0.27 beside an 11 ms lag refined to zeta 0.62 with a 25 ms dead time's
        remainder in it). Such an effect is another effect in disguise and held the others where
        they fitted around it: it goes *before* the others are final, and they are refined again.
        The selection record (``table``) keeps a row saying so.
        """
        table = list(table)
        while True:
            why = {a.name: a.effect.refusal(dict(a.nl), self.settings) or a.effect.implausible(dict(a.nl))
                   for a in config.actives if a.effect.search}
            bad = [n for n, w in why.items() if w]
            if not bad:
                return config, names, current, steps, table
            label = ", ".join(f"{k}={v:.3g}" for k, v in next(a for a in config.actives if a.name == bad[0]).nl.items())
            table.append({"effect": bad[0], "label": f"{bad[0]}({label})", "t": 0.0, "p": 1.0, "llr": 0.0,
                          "max_gain": 0.0, "ok": False, "note": f"dropped after the final refinement: {why[bad[0]]}"})
            config = config.without(bad[0])
            names = [n for n in names if not n.startswith(bad[0] + ".")]
            steps = [st for st in steps if st.candidate.effect.name != bad[0]]
            current = problem.fit(config, current.coefs(), names)
            if any(a.effect.search for a in config.actives):
                config, current = self._refine(problem, config, current.coefs(), names, current)

    def _candidates(self, problem, config, coefs, names, remaining, current, peaks_of, last_nl, progress):
        """Every remaining effect fitted beside the chosen ones (linear ones also in pairs; tones at each line)."""
        s = self.settings
        linear = [e for e in remaining if not e.search and not e.needs_peak]
        cands = self._linear_candidates(problem, config, coefs, names, linear)
        for e in remaining:
            if e.needs_peak:
                peaks = peaks_of(e, config, current) if peaks_of is not None else []
                strongest = sorted(peaks, key=lambda p: -max(p.ratio.values(), default=0.0))[: s.max_peaks]
                for pk in strongest:
                    cands.append(self._nonlinear_candidate(problem, config, coefs, names, e, pk))
            elif e.search:
                # after the first step, start from the last optimum (the landscape moves little)
                c = self._nonlinear_candidate(problem, config, coefs, names, e, start=last_nl.get(e.name))
                last_nl[e.name] = dict(c.active.nl)
                cands.append(c)
            if progress:
                progress(e.name)
        return cands

    def _judge_all(self, problem, cands, coefs, current, config, plausible):
        """Prune, judge every candidate on the held-out runs; returns (candidates, table, single-effect level)."""
        s = self.settings
        # Bonferroni within two families: single effects (each tone peak counts) and pairs of
        # linear effects (a pair must also beat its members alone by pair_margin); a library of
        # 15 linear effects has 105 pairs, which would otherwise drown every single effect
        n_pairs = sum(c.partner is not None for c in cands)
        n_single = len(cands) - n_pairs
        levels = {False: s.alpha / max(n_single, 1), True: s.alpha / max(n_pairs, 1)}
        table = []
        # entries of crosstalk and drift are chosen on the training runs before the held-out
        # judgement: a drift fitted in six channels where one drifts would lose in the other five
        cands = [self._prune(problem, c, coefs) if any(e.prunable for e in c.effects) else c for c in cands]
        for c in cands:
            self._assess(problem, c, coefs, current, config, levels[c.partner is not None], plausible)
            table.append(_row(c))
        single = {c.effect.name: c.test["llr"] for c in cands if c.partner is None}
        for c in cands:
            if c.partner is not None and c.ok:
                alone = max(single.get(c.effect.name, 0.0), single.get(c.partner.name, 0.0), 0.0)
                if c.test["llr"] < s.pair_margin * alone or alone == c.test["llr"]:
                    c.ok = False
                    c.note = f"no better than its members alone (x{s.pair_margin:g} needed)"
                    table[cands.index(c)].update(ok=False, note=c.note)
        return cands, table, levels[False]

    def _pick(self, problem, cands, table, coefs, current, config, level, plausible) -> Candidate | None:
        """The accepted candidate with the largest held-out gain (surrogate fits are judged again with the model)."""
        ok = [c for c in cands if c.ok]
        while ok:
            best = max(ok, key=lambda c: c.test["llr"])
            if not best.surrogate:
                return best
            # screened through the surrogate: the claim is judged with the model itself
            best.fit = problem.fit(best.config, coefs, best.names, surrogate=False)
            best.surrogate = False
            self._assess(problem, best, coefs, current, config, level, plausible)
            table[cands.index(best)] = _row(best)
            if best.ok:
                return best
            ok.remove(best)
        return None

    def _assess(self, problem, c: Candidate, coefs, current, config, level: float, plausible) -> None:
        """Judge a candidate on the held-out runs and check every claim criterion (sets ``c.ok``, ``c.note``)."""
        s = self.settings
        judged = self._judged(problem, c, coefs)
        corr = self._null_correction(problem, judged, coefs, current)
        c.test, c.gain_c = judge(current, judged.fit, judged.fit.grams, problem.settings.hac_lags, corr)
        reasons = []
        if c.test["p"] >= level:
            reasons.append(f"not significant (p={c.test['p']:.2g} >= {level:.2g})")
        if c.gain_c.max() < s.min_gain:
            reasons.append(f"held-out gain {c.gain_c.max():.1%} < {s.min_gain:.0%}")
        if not reasons:
            why = _implausible(c) or _refused(c, s)
            if why:
                reasons.append(f"implausible: {why}")
        if not reasons:
            why = _spans_zero(c, s.interval_z)
            if why:
                reasons.append(why)
        if not reasons and plausible is not None:
            ok, note = plausible(c, config, current)
            if not ok:
                reasons.append(note)
        c.ok = not reasons
        c.note = "; ".join(reasons)

    def _ambiguous(self, best: Candidate, cands: list[Candidate], level: float, hac: int,
                   separate_alpha: float) -> list[str]:
        """Effects that explain the held-out data about as well as ``best``: the data cannot separate them.

        A rival (a single effect) counts when it is significant on its own (at the step's level)
        and ``best`` does not beat it on the held-out blocks by a one-sided paired test (its
        held-out log-likelihood over the rival's) at ``separate_alpha``. Everything the campaign holds that separates two
        effects (zero-flow runs, the spread of flow speeds, of gait frequencies) enters that test.
        Per-run nuisance fits (a tone's phase) are left out: their gain is not comparable.
        """
        mine = {e.name for e in best.effects}
        out: list[str] = []
        if best.fit.grams.n_local:
            return out
        for c in cands:
            names = {e.name for e in c.effects}
            if c is best or c.partner is not None or names & mine or c.fit.grams.n_local:
                continue
            if c.test.get("p", 1.0) >= level or c.test["llr"] <= 0:
                continue
            if c.fit.sse_block_c.shape != best.fit.sse_block_c.shape:
                continue
            test, _ = judge(c.fit, best.fit, best.fit.grams, hac)
            if test["p"] >= separate_alpha:
                out += [n for n in names if n not in out]
        return out

    @staticmethod
    def _judged(problem, c: Candidate, coefs) -> Candidate:
        """The candidate as its held-out test sees it: refitted under its effect's judging values, if any.

        A single effect only (``Effect.judged_as``: per-run nuisance columns beside a drift); a pair
        is judged as fitted.
        """
        nl = c.effect.judged_as(dict(c.active.nl)) if c.partner is None else None
        if nl is None:
            return c
        act = Active(c.effect, nl)
        cfg = c.config.with_effect(act)
        return Candidate(c.effect, act, cfg, c.names, problem.fit(cfg, coefs, c.names))

    def _backward_check(self, problem, config, names, current, steps):
        """Drop effects that no longer earn their place once the others are final (collinear partners).

        Each effect, weakest first, is removed and the rest refitted; if the held-out test no
        longer clears the claim criteria for putting it back, it goes.
        """
        s = self.settings
        hac = problem.settings.hac_lags
        changed = True
        while changed and len(config.actives) > 1:
            changed = False
            level = s.alpha / len(config.actives)
            verdicts = []
            for a in config.actives:
                rest = config.without(a.name)
                rnames = [n for n in names if not n.startswith(a.name + ".")]
                f, after = problem.fit(rest, current.coefs(), rnames), current
                jn = a.effect.judged_as(dict(a.nl))
                if jn is not None:
                    # judged as at its step: beside its nuisance, against the nuisance alone
                    after = problem.fit(config.with_effect(Active(a.effect, jn)), current.coefs(), names)
                    nulls = a.effect.null_variants(jn)
                    if nulls:
                        f = problem.fit(config.with_effect(Active(a.effect, nulls[0])), current.coefs(), names)
                test, gain = judge(f, after, after.grams, hac)
                verdicts.append((test["llr"], a, rnames, test, gain))
            llr, a, rnames, test, gain = min(verdicts, key=lambda v: v[0])
            if test["p"] >= level or gain.max() < s.min_gain:
                config = config.without(a.name)
                names = rnames
                current = problem.fit(config, current.coefs(), names)
                steps = [st for st in steps if st.candidate.effect.name != a.name]
                changed = True
        return config, names, current, steps

    @staticmethod
    def _sample(problem) -> tuple[np.ndarray, np.ndarray]:
        """The base model's prediction on the first training batch and its fitted ticks (to configure effects)."""
        rs = problem.campaign.train_sets[0]
        d = problem.design(rs, Configuration(), {})
        return d.predict({}), rs.fit

    def _prune(self, problem, cand: Candidate, coefs) -> Candidate:
        """Drop individually insignificant entries of prunable effects (crosstalk, drift) and refit."""
        for e in cand.effects:
            if e.prunable:
                cand = self._prune_one(problem, cand, e)
        return cand

    def _prune_one(self, problem, cand: Candidate, e: Effect) -> Candidate:
        own = [n for n in cand.names if n.startswith(e.name + ".")]
        zc = stats.norm.isf(self.settings.prune_alpha / (2 * max(len(own), 1)))
        keep = list(own)
        gr = cand.fit.grams
        # backward elimination: drop the weakest entry and refit until every entry left is significant;
        # an entry outside its plausible range whose column is nearly that of a plausible entry in
        # the same channel is that entry's alias (tz = 0.02 fy makes x_fz_tz = 1.5 read as x_fz_fy =
        # 0.03) and goes first, whatever its z
        while len(keep) > 1:
            names = [n for n in cand.names if n not in own] + keep
            f = lsq.fit(gr.subset(names), problem.weights, problem.settings.hac_lags)
            co, se = f.coefs(), f.stderr()
            alias = _implausible_alias(e, gr, keep, co)
            if alias is not None:
                keep.remove(alias)
                continue
            z = {n: abs(co[n]) / se[n] if se[n] > 0 else 0.0 for n in keep}
            weakest = min(keep, key=z.get)
            if z[weakest] >= zc:
                break
            keep.remove(weakest)
        if len(keep) == len(own):
            return cand
        names = [n for n in cand.names if n not in own] + keep
        sub = gr.subset(names)
        f = lsq.fit(sub, problem.weights, problem.settings.hac_lags)
        f.grams = sub  # type: ignore[attr-defined]
        return Candidate(cand.effect, cand.active, cand.config, names, f, cand.test, cand.gain_c, cand.profile,
                         cand.ok, cand.note, cand.partner)

    def _parabola(self, problem, config, coefs, names, effect, start: dict) -> dict:
        """The first searched parameter finished by a parabola through three values around ``start`` (others kept).

        Log-scaled parameters (a lag) at start x exp(-0.12, 0, 0.12); others at start -+ 0.03.
        """
        p = effect.search[0]
        extra = [f"{effect.name}.{n}" for n in effect.linear_names()]

        def objective(v: float) -> float:
            cfg = config.with_effect(Active(effect, {**start, p.name: v}))
            gr = problem.grams(cfg, coefs, names + extra, sets="search")
            return float(lsq.fit(gr, problem.weights, problem.settings.hac_lags).sse_block.sum())

        v0 = float(start[p.name])
        if p.log and v0 <= 0:
            return start
        width = 0.12 if p.log else 0.03
        x0 = np.log(v0) if p.log else v0
        xs = x0 + np.array([-width, 0.0, width])

        def value(x: float) -> float:
            return float(np.clip(np.exp(x) if p.log else x, *p.bounds))

        ys = np.array([objective(value(x)) for x in xs])
        best = value(xs[int(np.argmin(ys))])
        vx = _parabola_min(xs, ys)
        if vx is not None and abs(vx - x0) <= 2 * width:
            v = value(vx)
            if objective(v) < ys.min():
                best = v
        return {**start, p.name: best}

    def _refine(self, problem, config, coefs, names, current):
        """Re-search each nonlinear parameter with the others at their final values (one round).

        Always with the model itself (no lagged-output surrogate): these are the reported values.
        """
        surrogate = getattr(problem, "surrogate_search", False)
        problem.surrogate_search = False
        try:
            for a in list(config.actives):
                if not a.effect.search:
                    continue
                rest = config.without(a.name)
                if surrogate and a.effect.stage == "input":
                    # the surrogate's optimum is right to first order: a parabola through three
                    # evaluations of the model itself finishes its first searched parameter (each
                    # costs a full model run; a shape parameter keeps the surrogate's value)
                    nl = self._parabola(problem, rest, coefs, names, a.effect, dict(a.nl))
                elif a.effect.lookahead:
                    # a delay's optimum moves as the force effects come in, and a warm start from an
                    # early step can sit in its old basin (a dead time found as a short pure lag):
                    # its whole grid is searched again, the current values added to it
                    grids = {p.name: tuple(sorted({*p.grid, float(a.nl[p.name])})) for p in a.effect.search}
                    nl, _ = self.search(problem, rest, coefs, names, a.effect, grids=grids)
                else:
                    nl, _ = self.search(problem, rest, coefs, names, a.effect, start=dict(a.nl))
                config = rest.with_effect(Active(a.effect, nl))
        finally:
            problem.surrogate_search = surrogate
        current = problem.fit(config, coefs, names)
        return config, current


def _row(c: Candidate) -> dict:
    """A candidate's line in the selection record."""
    return {"effect": c.effect.name, "label": c.label + (" (surrogate)" if c.surrogate else ""), "t": c.test["t"],
            "p": c.test["p"], "llr": c.test["llr"], "max_gain": float(c.gain_c.max()), "ok": c.ok, "note": c.note}


#: rounds the selection may go on after the final refinement has moved a look-ahead effect's values
FOLLOW_ROUNDS = 2


def _around(effect: Effect, nl: dict) -> dict[str, tuple]:
    """A small grid around an effect's searched values: each value and its neighbours on the effect's own grid."""
    out = {}
    for p in effect.search:
        v = float(nl.get(p.name, np.median(p.grid)))
        grid = sorted({*p.grid, v})
        i = grid.index(v)
        out[p.name] = tuple(grid[max(i - 1, 0): i + 2])
    return out


def _snap(v: float, p) -> float:
    """A searched value on a coarse grid (2 % steps in log, 0.005 otherwise), inside its bounds."""
    if p.log and v > 0:
        v = float(np.exp(np.round(np.log(v) / 0.02) * 0.02))
    else:
        v = float(np.round(v / 0.005) * 0.005)
    return float(np.clip(v, *p.bounds))


def _parabola_min(x: np.ndarray, y: np.ndarray) -> float | None:
    """Vertex of the parabola through three points (None when it opens downwards)."""
    a, b, _ = np.polyfit(x, y, 2)
    return float(-b / (2 * a)) if a > 0 else None


def _implausible_alias(e: Effect, gr: lsq.Grams, keep: list[str], coefs: dict, collinear: float = 0.95) -> str | None:
    """The most implausible of ``keep`` (qualified names of ``e``'s entries) that aliases a plausible one.

    Two entries alias when their columns in the same channel are nearly proportional (|cosine|
    at least ``collinear`` over the training blocks); only the plausible one of the two is
    physics, the other reads the same signal through a proportional source.
    """
    def outside(n: str) -> float:
        short = n.split(".", 1)[1]
        if not e.implausible({short: coefs[n]}):
            return 0.0
        rng = e.ranges.get(short) or next((r for pat, r in e.ranges.items()
                                            if pat.endswith("*") and short.startswith(pat[:-1])), (0.0, 0.0))
        return abs(coefs[n]) / max(abs(rng[0]), abs(rng[1]), 1e-300)

    bad = sorted((n for n in keep if outside(n) > 0), key=outside, reverse=True)
    if not bad:
        return None
    pos = {n: i for i, n in enumerate(gr.names)}
    train = ~gr.heldout
    for n in bad:
        for c in range(6):
            cols = list(gr.chan_cols[c])
            if pos[n] not in cols:
                continue
            g = gr.G[c][train].sum(axis=0)
            i = cols.index(pos[n])
            for m in keep:
                if m == n or outside(m) > 0 or pos[m] not in cols:
                    continue
                j = cols.index(pos[m])
                if abs(g[i, j]) >= collinear * np.sqrt(max(g[i, i] * g[j, j], 1e-300)):
                    return n
    return None


def _implausible(c: Candidate) -> str | None:
    """The candidate's canonical parameters outside its plausible ranges (it would absorb another misfit)."""
    for e in c.effects:
        own = {k.split(".", 1)[1]: v for k, v in c.fit.coefs().items() if k.split(".", 1)[0] == e.name}
        nl = dict(c.active.nl) if e is c.effect else {}
        try:
            params, _ = e.canonical_params(own, nl, {}, None)
        except (ValueError, ZeroDivisionError, KeyError):
            continue
        why = e.implausible({k: v for k, v in params.items() if isinstance(v, (int, float))})
        if why:
            return f"{e.name}: {why}"
    return None


def magnitude_intervals(params: dict, stderr: dict, z: float = 1.96, location=None) -> dict[str, bool]:
    """Per magnitude parameter with a finite error: whether its interval ``value +- z se`` holds zero.

    ``location``: the effect's parameters that locate it rather than measure it
    (:attr:`~workbench.diagnose.effects.base.Effect.location_params`); None: those of every effect
    in the table.
    """
    if location is None:
        from workbench.diagnose.library import location_params

        location = location_params()
    out = {}
    for k, v in params.items():
        if k in location or not isinstance(v, (int, float)) or isinstance(v, bool):
            continue
        se = stderr.get(k)
        if se is None or not np.isfinite(se) or not np.isfinite(v):
            continue
        out[k] = abs(v) <= z * se
    return out


def _spans_zero(c: Candidate, z: float) -> str | None:
    """Why a candidate is refused for an interval that spans zero (linear parameters; None when clear).

    An effect is claimed only if at least one of its magnitude parameters is clear of zero;
    the errors here are the training fit's sandwich errors (clusters = runs). Searched
    parameters (a lag's time constant) are checked once their profiled error is known (loop).
    """
    cov_names = list(c.fit.names)
    for e in c.effects:
        if e.search:
            continue
        own = {k.split(".", 1)[1]: v for k, v in c.fit.coefs().items() if k.split(".", 1)[0] == e.name}
        idx = {n.split(".", 1)[1]: i for i, n in enumerate(cov_names) if n.split(".", 1)[0] == e.name}
        cov = {(a, b): float(c.fit.cov[i, j]) for a, i in idx.items() for b, j in idx.items()}
        try:
            params, se = e.canonical_params(own, {}, cov, None)
        except (ValueError, ZeroDivisionError, KeyError):
            continue
        spans = magnitude_intervals(params, se, z, e.location_params)
        if spans and all(spans.values()):
            k = next(iter(spans))
            return f"{e.name}: 95 % interval of {k} ({params[k]:.3g} +- {z * se[k]:.2g}) spans zero"
    return None


def _refused(c: Candidate, settings: SelectionSettings) -> str | None:
    """The candidate's searched values are another effect in disguise (its own rule, e.g. a damped mode is a delay)."""
    why = c.effect.refusal(dict(c.active.nl), settings)
    return f"{c.effect.name}: {why}" if why else None


def _heldout_mse(f: lsq.Fit) -> np.ndarray:
    h = f.grams.heldout
    return f.sse_block_c[h].sum(axis=0) / max(f.grams.n[h].sum(), 1)


CHANNELS = list(WRENCH_CHANNELS)
