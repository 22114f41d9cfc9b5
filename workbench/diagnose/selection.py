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

The selection's parts, each readable alone: :mod:`~workbench.diagnose.selection_records` (settings,
candidates, steps, result), :mod:`~workbench.diagnose.selection_judge` (the held-out test),
:mod:`~workbench.diagnose.selection_search` (nonlinear parameters), :mod:`~workbench.diagnose.selection_candidates`
(the candidates of a step, pruning), :mod:`~workbench.diagnose.selection_claims` (the claim criteria,
the pick, ambiguity) and :mod:`~workbench.diagnose.selection_finish` (final refinement and backward
check). This module holds the paths: the greedy steps, the look-ahead branches and their end.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose import lsq
from workbench.diagnose.chain import Active, Configuration
from workbench.diagnose.effects.base import Effect, EffectLibrary
from workbench.diagnose.selection_candidates import candidates, held_at_bounds
from workbench.diagnose.selection_claims import ambiguous, assess, judge_all, magnitude_intervals, pick  # noqa: F401
from workbench.diagnose.selection_finish import backward_check, drop_refused, drop_unsupported, refine, settle
from workbench.diagnose.selection_judge import _null_spread_test, block_llr, heldout_mse, judge  # noqa: F401
from workbench.diagnose.selection_records import (  # noqa: F401 - importable from here as before the split
    Candidate,
    SelectionResult,
    SelectionSettings,
    Step,
    record_row,
)
from workbench.diagnose.selection_search import around, search


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
    #: whether the round budget (``max_effects``) ran out before the path stopped by itself
    budget_spent: bool = False
    #: per line's effect (``needs_peak``), the frequencies it was acceptable at in an earlier round
    lines: dict = field(default_factory=dict)
    #: near ties passed over (``SelectionSettings.tie_branches``): the runner-up's branch at its step
    ties: list = field(default_factory=list)

    def copy(self) -> "_Path":
        """An independent copy (fits are shared: they are not changed in place)."""
        return _Path(self.config.copy(), list(self.names), self.current, dict(self.coefs), list(self.steps),
                     list(self.table), {k: dict(v) for k, v in self.last_nl.items()}, self.rounds, [],
                     lines={k: list(v) for k, v in self.lines.items()})


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
        return search(self.settings, problem, config, coefs, names, effect, grids, start)

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
        paths = (self._force(problem, b, plausible) for b in main.branches[: s.lookahead_branches]
                 if b.forced.effect.name not in result.config.names())
        for path in paths:
            result = self._better(problem, result, path, more)
        if s.seeded_branches:
            for e in library:
                if not e.lookahead or e.name in result.config.names():
                    continue
                seeded = e.seed(problem, result.config)
                if seeded is not None:
                    result = self._better(problem, result, self._seeded(problem, start, e, *seeded, plausible), more)
        # the near ties of the path that won (the greedy one or a branch), one level: a tie branch's own ties are not followed
        for b in result.near_ties[: s.tie_branches]:
            result = self._better(problem, result, self._force(problem, b, plausible), more)
        if result.budget_spent:
            result.left_at_budget = self._left(problem, library, result, peaks_of, plausible, progress)
        return result

    def _better(self, problem, result: SelectionResult, path: "_Path | None", more: tuple) -> SelectionResult:
        """The branch ``path`` followed to its end when its held-out fit beats ``result``'s at ``alpha``, else ``result``.

        A branch whose greedy steps end with a held-out fit no better than ``result``'s final one is
        not finished: its refinement and backward check cost more than its steps (measured: 67 and
        36 s of a 129 and 55 s diagnosis, a servo branch seeded beside a planted mount mode), and
        they did not turn a losing branch into a winner (there, both dropped the servo again and
        ended as the greedy result). The servo branches that win are far ahead before finishing
        (held-out log-likelihood ratio +21,500 to +23,000 on the battery's dead times).
        """
        if path is None:
            return result
        ahead = self._forward(problem, more[0], path, *more[1:])
        test, _ = judge(result.fit, ahead.current, ahead.current.grams, problem.settings.hac_lags)
        if not test["llr"] > 0:
            return result
        alt = self._finish(problem, ahead, more)
        test, _ = judge(result.fit, alt.fit, alt.fit.grams, problem.settings.hac_lags)
        return alt if test["llr"] > 0 and test["p"] < self.settings.alpha else result

    def _seeded(self, problem, start: "_Path", effect: Effect, nl: dict, why: str, plausible) -> "_Path":
        """The path that starts with ``effect`` at the values its own evidence points to (:meth:`Effect.seed`).

        The effect is held at ``nl`` for the first step (a search there would go back to the value the
        base model's misfit biases it to) and followed after every later step like any chosen
        look-ahead effect. Its held-out test is recorded, not required: the branch as a whole must
        beat the greedy path, and the backward check drops the effect if it no longer earns its place.
        """
        path = start.copy()
        act = Active(effect, dict(nl))
        cfg = path.config.with_effect(act)
        names = path.names + [f"{effect.name}.{n}" for n in effect.linear_names()]
        c = Candidate(effect, act, cfg, names, problem.fit(cfg, path.coefs, names))
        assess(self.settings, problem, c, path.coefs, path.current, path.config, self.settings.alpha, plausible)
        c.note = f"branch seeded by the data: {why}" + (f" (alone: {c.note})" if c.note else "")
        self._accept(problem, path, c, [record_row(c)], [], [])
        path.last_nl[effect.name] = dict(nl)
        return path

    def _forward(self, problem, library, path: "_Path", peaks_of, plausible, progress) -> "_Path":
        """Greedy steps from ``path`` until no candidate is accepted; look-ahead effects passed over are recorded."""
        s = self.settings
        hac = problem.settings.hac_lags
        path = path.copy()
        while path.rounds < s.max_effects:
            path.rounds += 1
            self._release(problem, path)
            config, names, current, coefs = path.config, path.names, path.current, path.coefs
            remaining = [e for e in library if e.name not in config.names()]
            cands = candidates(s, problem, config, coefs, names, remaining, current, peaks_of, path.last_nl, progress,
                               kept_lines=path.lines)
            if not cands:
                break
            cands, table, level = judge_all(s, problem, cands, coefs, current, config, plausible)
            path.table = table
            _keep_lines(path, cands)
            best = pick(s, problem, cands, table, coefs, current, config, level, plausible)
            if best is None and s.held_fallback:
                best = self._held(problem, cands, table, coefs, current, config, level, plausible)
            if best is None:
                break
            mine = {e.name for e in best.effects}
            seen = {b.forced.effect.name for b in path.branches}
            for c in cands:
                if (c.ok and c is not best and c.partner is None and c.effect.lookahead
                        and c.effect.name not in mine | seen):
                    path.branches.append(_Branch(path.copy(), c, level))
            self._near_ties(path, cands, best, level)
            alternatives = [c.label for c in _runners_up(cands, best, s.ambiguity_ratio) if c.test["llr"] > 0]
            rivals = ambiguous(best, cands, level, hac, s.alpha)
            self._accept(problem, path, best, table, alternatives, rivals)
            self._follow(problem, path, mine)
        else:
            path.budget_spent = True
        return path

    def _near_ties(self, path: "_Path", cands, best: Candidate, level: float) -> None:
        """Record (in place) the step's near tie, while fewer than ``tie_branches`` are recorded.

        The near tie is the best runner-up sharing no effect with ``best`` whose held-out log-likelihood
        ratio is within ``tie_ratio`` of it.

        Measured (the fourth probe, a 10 + 40 ms command servo beside a static hip torque, EF, no reference):
        at step 2 two pairs of force effects tied within 1 % (6049 against 5983); the greedy pick led to a
        path that stalled after five effects with the servo 40 % short and the planted error worse than the EF's.
        """
        s = self.settings
        if len(path.ties) >= s.tie_branches or best.test["llr"] <= 0:
            return
        rivals = [c for c in _runners_up(cands, best, s.tie_ratio) if c.ok]
        if rivals:
            path.ties.append(_Branch(path.copy(), max(rivals, key=lambda c: c.test["llr"]), level))

    def _left(self, problem, library, result: SelectionResult, peaks_of, plausible, progress) -> list[dict]:
        """Rows of candidates still acceptable beside the final claims: one more round, judged only.

        Run when the round budget (``max_effects``) ran out: a greedy selection cut off by its
        budget has not converged, and what it would still claim is recorded (and reported beside
        the claims), not silently dropped.
        """
        config, names, current = result.config, result.names, result.fit
        coefs = current.coefs()
        remaining = [e for e in library if e.name not in config.names()]
        last_nl = {a.name: dict(a.nl) for a in config.actives}
        cands = candidates(self.settings, problem, config, coefs, names, remaining, current, peaks_of, last_nl, progress)
        if not cands:
            return []
        _, table, _ = judge_all(self.settings, problem, cands, coefs, current, config, plausible)
        return [dict(row) for row in table if row.get("ok")]

    def _held(self, problem, cands, table, coefs, current, config, level, plausible) -> Candidate | None:
        """When no candidate can be claimed: the best refused one with its amplitudes past a zero bound held there.

        A circulatory lag whose fast share fits slightly past zero (another effect's misfit, not yet
        modelled, pulls it there) is refused as implausible although its other amplitude carries
        most of the held-out error (measured on the demo campaign with a planted 5 % fz-from-fy
        crosstalk: 69 % of the held-out error, p 5e-30, refused at every step, the selection stopped
        after six effects and the crosstalk went unnamed). Only when the step would otherwise end
        the selection, each single linear candidate refused as implausible is refitted with such
        amplitudes held at 0 (:func:`~workbench.diagnose.selection_candidates.held_at_bounds`) and
        judged again by every criterion at the step's level; the held amplitudes are freed at a
        later step once they fit inside their range (:meth:`_release`). Tried first rather than
        last, the held form came in early on the battery's campaign and was never freed.
        """
        out = []
        for c in cands:
            if c.partner is not None or c.effect.search or c.effect.needs_peak or c.ok:
                continue
            if not c.note.startswith("implausible") or getattr(c.fit, "grams", None) is None:
                continue
            names, fit = held_at_bounds(problem, c.fit.grams, list(c.names), c.effects, c.fit)
            if names == list(c.names):
                continue
            h = Candidate(c.effect, c.active, c.config, names, fit)
            assess(self.settings, problem, h, coefs, current, config, level, plausible)
            h.note = "amplitudes past a zero bound held at it" + (f"; {h.note}" if h.note else "")
            table.append(record_row(h))
            if h.ok:
                out.append(h)
        return max(out, key=lambda c: c.test["llr"]) if out else None

    @staticmethod
    def _release(problem, path: "_Path") -> None:
        """Amplitudes held at a zero bound (:func:`held_at_bounds`) fitted again once they come back inside it (in place).

        Held early in the selection, a circulatory lag's fast share stayed 0 in the clean demo
        campaign although, with the other force effects in, it fits at 0.36: the effects that
        came after took its part (a crosstalk among them). Each step first refits with the held
        amplitudes free and keeps them when every one of them lies within its range.
        """
        held = [f"{a.name}.{n}" for a in path.config.actives if not a.effect.prunable
                and len(a.effect.linear_names()) >= 2 for n in a.effect.linear_names()
                if f"{a.name}.{n}" not in path.names and 0.0 in a.effect.ranges.get(n, (None, None))]
        if not held:
            return
        names = path.names + held
        fit = problem.fit(path.config, path.coefs, names)
        co = fit.coefs()
        for q in held:
            eff = next(a.effect for a in path.config.actives if q.startswith(a.name + "."))
            lo, hi = eff.ranges.get(q.split(".", 1)[1], (-np.inf, np.inf))
            if not lo <= co[q] <= hi:
                return
        path.names, path.current, path.coefs = names, fit, co

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
            nl, _ = self.search(problem, rest, path.coefs, path.names, a.effect, grids=around(a.effect, a.nl))
            if all(abs(nl[k] - a.nl.get(k, np.nan)) <= 1e-9 * max(abs(nl[k]), 1.0) for k in nl):
                continue
            path.config = rest.with_effect(Active(a.effect, nl))
            path.current = problem.fit(path.config, path.coefs, path.names)
            path.coefs = path.current.coefs()
            path.last_nl[a.name] = dict(nl)

    @staticmethod
    def _accept(problem, path: "_Path", best: Candidate, table, alternatives, ambiguous) -> None:
        """Take ``best`` into ``path`` (in place) and record its step."""
        before_c = heldout_mse(path.current)
        path.config, path.names = best.config, best.names
        path.current = problem.fit(path.config, path.coefs, path.names)
        path.coefs = path.current.coefs()
        for e in best.effects:
            member = Candidate(e, Active(e, dict(best.active.nl) if e is best.effect else {}), best.config,
                               best.names, best.fit, best.test, best.gain_c, best.profile, True, best.note)
            other = next((o.name for o in best.effects if o is not e), None)
            path.steps.append(Step(member, before_c, heldout_mse(path.current), table, alternatives,
                                   [n for n in ambiguous if n != e.name], partner=other))

    def _force(self, problem, branch: "_Branch", plausible) -> "_Path | None":
        """The branch's path with its passed-over effect accepted (judged with the model itself; None if it fails)."""
        path = branch.path.copy()
        c = branch.forced
        if c.surrogate:
            c.fit = problem.fit(c.config, path.coefs, c.names, surrogate=False)
            c.surrogate = False
            assess(self.settings, problem, c, path.coefs, path.current, path.config, branch.level, plausible)
            if not c.ok:
                return None
        self._accept(problem, path, c, path.table, [], [])
        return path

    def _finish(self, problem, path: "_Path", more: tuple | None = None) -> SelectionResult:
        """Refine the searched parameters jointly, then drop effects that no longer earn their place.

        ``more`` (library, peaks_of, plausible, progress): an effect with a structural check is
        checked again at its refined values (``plausible``) and dropped if it fails there; when the
        refinement has moved a look-ahead effect's values (a delay), or an effect was dropped so, the
        selection goes on from the refined configuration (an effect the held delay's remainder, or
        the dropped effect, hid, such as a drift, may now be significant), and the new
        configuration is refined again.
        """
        config, names, current = path.config, path.names, path.current
        steps, table = list(path.steps), path.table
        spent = path.budget_spent
        if self.settings.refine and any(a.effect.search for a in config.actives):
            before = config.nl_values()
            config, current = refine(self.settings, problem, config, path.coefs, names, current)
            if self._following(problem):
                config, names, current, steps, table = drop_refused(self.settings, problem, config, names, current, steps, table)
            had = len(config.actives)
            config, names, current, steps, table = drop_unsupported(self.settings, problem, config, names, current,
                                                                    steps, table, more and more[2])
            moved = any(a.effect.lookahead and any(abs(v - before.get(f"{a.name}.{k}", np.nan)) > 1e-9
                                                   for k, v in a.nl.items()) for a in config.actives)
            # an effect dropped at its final values held the others where they fitted around it: the
            # selection goes on without it too (an effect it hid may now be significant)
            moved = moved or len(config.actives) < had
            if more is not None and moved and self._following(problem):
                # the selection goes on from the refined values, for at most ``FOLLOW_ROUNDS`` more rounds
                go = _Path(config, list(names), current, current.coefs(), steps, table,
                           {a.name: dict(a.nl) for a in config.actives},
                           min(path.rounds, self.settings.max_effects - FOLLOW_ROUNDS))
                go = self._forward(problem, more[0], go, *more[1:])
                if len(go.config.actives) > len(config.actives):
                    config, names, current, steps, table = go.config, go.names, go.current, go.steps, go.table
                    spent = go.budget_spent
                    config, current = refine(self.settings, problem, config, current.coefs(), names, current)
                    config, names, current, steps, table = drop_refused(self.settings, problem, config, names, current, steps, table)
                    config, names, current, steps, table = drop_unsupported(self.settings, problem, config, names,
                                                                            current, steps, table, more[2])
        names, current, change = settle(self.settings, problem, config, names, current, tol=SETTLE_TOL)
        if change > SETTLE_TOL:
            # a fixed point not reached is not a result: the record says so beside the claims
            table = [*table, {"effect": "settle", "label": "settle", "t": 0.0, "p": 1.0, "llr": 0.0, "max_gain": 0.0,
                              "ok": False, "note": f"crosstalk/drift entries did not settle: last change {change:.2g}"}]
        table = list(table)
        config, names, current, steps = backward_check(self.settings, problem, config, names, current, steps, table)
        return SelectionResult(config, names, current, steps, table, budget_spent=spent, near_ties=list(path.ties))

    @staticmethod
    def _sample(problem) -> tuple[np.ndarray, np.ndarray]:
        """The base model's prediction on the first training batch and its fitted ticks (to configure effects)."""
        rs = problem.campaign.train_sets[0]
        d = problem.design(rs, Configuration(), {})
        return d.predict({}), rs.fit


def _runners_up(cands, best: Candidate, ratio: float) -> list:
    """Candidates other than ``best``, sharing none of its effects, whose held-out LLR reaches ``ratio`` of its."""
    mine = {e.name for e in best.effects}
    return [c for c in cands if c is not best and not {e.name for e in c.effects} & mine
            and c.test["llr"] >= ratio * best.test["llr"]]


def _keep_lines(path: _Path, cands) -> None:
    """Remember the lines each line's effect was acceptable at this round (in place; see ``candidates``)."""
    for c in cands:
        if c.ok and c.partner is None and c.effect.needs_peak:
            f0 = float(c.active.nl[c.effect.search[0].name])
            kept = path.lines.get(c.effect.name, [])
            if all(abs(f0 - f) > 1e-6 for f in kept):
                path.lines[c.effect.name] = [*kept, f0]


#: largest change of a crosstalk's or drift's entries in the last refit for them to count as settled
SETTLE_TOL = 1e-4

#: rounds the selection may go on after the final refinement has moved a look-ahead effect's values
FOLLOW_ROUNDS = 2

CHANNELS = list(WRENCH_CHANNELS)
