"""The claim criteria of one selection step: which candidates may be claimed, and which one is.

Every candidate is judged on the held-out runs (:func:`~workbench.diagnose.selection_judge.judge`,
against off-peak variants of its per-run nuisance fit where it has one) at a Bonferroni level
within its family (single effects, pairs of linear effects), and must remove ``min_gain`` of a
channel's held-out error, keep its parameters plausible, have a magnitude interval clear of zero
and pass the caller's structural checks (:func:`assess`). A pair must beat its members alone by
``pair_margin`` (:func:`judge_all`); the accepted candidate with the largest gain wins
(:func:`pick`), and the rivals the data cannot separate from it are reported (:func:`ambiguous`).
"""

from __future__ import annotations

import numpy as np

from workbench.diagnose import lsq
from workbench.diagnose.chain import Active
from workbench.diagnose.selection_candidates import prune
from workbench.diagnose.selection_judge import block_llr, crossfit_judge, judge
from workbench.diagnose.selection_records import Candidate, SelectionSettings, record_row


def judge_all(s: SelectionSettings, problem, cands, coefs, current, config, plausible):
    """Prune, judge every candidate on the held-out runs; returns (candidates, table, single-effect level)."""
    # Bonferroni within two families: single effects (each tone peak counts) and pairs of
    # linear effects (a pair must also beat its members alone by pair_margin); a library of
    # 15 linear effects has 105 pairs, which would otherwise drown every single effect
    n_pairs = sum(c.partner is not None for c in cands)
    n_single = len(cands) - n_pairs
    levels = {False: s.alpha / max(n_single, 1), True: s.alpha / max(n_pairs, 1)}
    table = []
    # entries of crosstalk and drift are chosen on the training runs before the held-out
    # judgement: a drift fitted in six channels where one drifts would lose in the other five
    cands = [prune(s, problem, c, coefs) if any(e.prunable for e in c.effects) else c for c in cands]
    for c in cands:
        assess(s, problem, c, coefs, current, config, levels[c.partner is not None], plausible)
        table.append(record_row(c))
    single = {c.effect.name: c.test["llr"] for c in cands if c.partner is None}
    for c in cands:
        if c.partner is not None and c.ok:
            alone = max(single.get(c.effect.name, 0.0), single.get(c.partner.name, 0.0), 0.0)
            if c.test["llr"] < s.pair_margin * alone or alone == c.test["llr"]:
                c.ok = False
                c.note = f"no better than its members alone (x{s.pair_margin:g} needed)"
                table[cands.index(c)].update(ok=False, note=c.note)
    return cands, table, levels[False]


def pick(s: SelectionSettings, problem, cands, table, coefs, current, config, level, plausible) -> Candidate | None:
    """The accepted candidate with the largest held-out gain (surrogate fits are judged again with the model)."""
    ok = [c for c in cands if c.ok]
    while ok:
        best = max(ok, key=lambda c: c.test["llr"])
        if not best.surrogate:
            return best
        # screened through the surrogate: the claim is judged with the model itself
        best.fit = problem.fit(best.config, coefs, best.names, surrogate=False)
        best.surrogate = False
        assess(s, problem, best, coefs, current, config, level, plausible)
        table[cands.index(best)] = record_row(best)
        if best.ok:
            return best
        ok.remove(best)
    return None


def assess(s: SelectionSettings, problem, c: Candidate, coefs, current, config, level: float, plausible) -> None:
    """Judge a candidate on the held-out runs and check every claim criterion (sets ``c.ok``, ``c.note``)."""
    judged = _judged(problem, c, coefs)
    fits = variant_fits(problem, judged.effect, judged.config, judged.active.nl, judged.names, coefs)
    plan = crossfit_plan(s, judged, fits, current)
    if plan is not None:
        before, variants = plan
        telling = telling_blocks(problem, judged.effect, judged.active.nl, judged.fit.grams) if variants else None
        c.test, c.gain_c = crossfit_judge(before, judged.fit, problem.block_folds(judged.fit.grams, s.judge_folds),
                                          problem.weights, problem.settings.hac_lags, variants, telling)
    else:
        corr, null_sse = variant_correction(fits, current)
        telling = (telling_blocks(problem, judged.effect, judged.active.nl, judged.fit.grams)
                   if null_sse is not None else None)
        c.test, c.gain_c = judge(current, judged.fit, judged.fit.grams, problem.settings.hac_lags, corr, null_sse,
                                 telling)
    reasons = []
    if c.test["p"] >= level:
        reasons.append(f"not significant (p={c.test['p']:.2g} >= {level:.2g})")
    practical = c.effect.practical_gain(c.gain_c)
    if practical.max() < s.min_gain:
        reasons.append(f"held-out gain {practical.max():.1%} < {s.min_gain:.0%}")
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
    names = c.names + [f"{c.effect.name}.{n}" for n in c.effect.judging_names(nl, c.names)]
    return Candidate(c.effect, act, cfg, names, problem.fit(cfg, coefs, names))


def telling_blocks(problem, effect, nl: dict, grams: lsq.Grams) -> np.ndarray | None:
    """Per block: whether its run can tell ``effect`` from the misfit (:meth:`Effect.telling_runs`; None: all)."""
    runs = np.ones(len(problem.campaign.runs), bool)
    told = False
    for rs in problem.campaign.sets:
        m = effect.telling_runs(dict(nl), rs)
        if m is not None:
            runs[np.asarray(rs.index)] = np.asarray(m, bool)
            told = True
    return runs[grams.run] if told else None


def variant_fits(problem, effect, config, nl: dict, names: list[str], coefs) -> list[lsq.Fit]:
    """The fits of ``effect``'s null variants of ``nl`` in ``config`` (none without variants)."""
    return [problem.fit(config.with_effect(Active(effect, v)), coefs, names) for v in effect.null_variants(nl)]


def variant_correction(fits: list[lsq.Fit], current: lsq.Fit):
    """What the same per-run fit gains at its off-peak variants (``fits``) over ``current``, for :func:`judge`.

    Returns per block the variants' log-likelihood gain, ``(k, nb)``, and their squared error per
    block and channel, ``(k, nb, channels)``; ``(None, None)`` without variants.
    """
    if not fits:
        return None, None
    gains = [block_llr(current, f, f.grams).sum(axis=1) for f in fits]
    return np.array(gains), np.array([f.sse_block_c for f in fits])


def crossfit_plan(s: SelectionSettings, judged: Candidate, fits: list[lsq.Fit], current: lsq.Fit):
    """What a cross-fitted judgement of ``judged`` tests against, ``(before, variants)``; None: the split.

    ``before``: its one null variant (a nuisance alone), else ``current``; ``variants``: three or
    more off-peak variants of a per-run fit (a tone's phases), tested against their spread. Two
    variants, or a pair of effects, stay on the split.
    """
    if judged.partner is not None or len(fits) == 2:
        return None
    before, variants = (fits[0], []) if len(fits) == 1 else (current, fits)
    return (before, variants) if crossfit_applies(s, judged.effect, before, judged.fit, variants) else None


def crossfit_applies(s: SelectionSettings, effect, before: lsq.Fit, after: lsq.Fit, variants: list = ()) -> bool:
    """Whether ``effect`` is judged cross-fitted between these fits.

    It asks for it (``Effect.crossfit``, ``judge_folds`` of 2 or more), and the fits hold the same
    blocks; per-run columns only where at least three off-peak variants weigh what a per-run fit
    gains on noise (a per-run fit gains in its own run, held out or not).
    """
    if not effect.crossfit or s.judge_folds < 2:
        return False
    grams = [after.grams, getattr(before, "grams", None), *(getattr(v, "grams", None) for v in variants)]
    if any(g is None for g in grams) or len({len(g.n) for g in grams}) != 1:
        return False
    return not any(g.n_local for g in grams) or len(variants) >= 3


def ambiguous(best: Candidate, cands: list[Candidate], level: float, hac: int,
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


def magnitude_intervals(params: dict, stderr: dict, z: float = 1.96, location=None, negligible=None) -> dict[str, bool]:
    """Per magnitude parameter with a finite error: whether its interval ``value +- z se`` holds zero.

    ``location``: the effect's parameters that locate it rather than measure it
    (:attr:`~workbench.diagnose.effects.base.Effect.location_params`); None: those of every effect
    in the table. ``negligible``: name -> half-width of a band around zero the interval must clear
    instead (:meth:`~workbench.diagnose.effects.base.Effect.negligible_of`); None: zero itself.
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
        out[k] = abs(v) - z * se <= (negligible(k) if negligible is not None else 0.0)
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
        spans = magnitude_intervals(params, se, z, e.location_params, e.negligible_of)
        if spans and all(spans.values()):
            k = next(iter(spans))
            return f"{e.name}: 95 % interval of {k} ({params[k]:.3g} +- {z * se[k]:.2g}) {_reaches(e, k)}"
    return None


def _reaches(effect, name: str) -> str:
    """What an interval that is not clear reaches: zero, or the effect's negligible band around it."""
    band = effect.negligible_of(name)
    return f"reaches into the negligible band |{name}| <= {band:g}" if band > 0 else "spans zero"


def _refused(c: Candidate, settings: SelectionSettings) -> str | None:
    """The candidate's searched values are another effect in disguise (its own rule, e.g. a damped mode is a delay)."""
    why = c.effect.refusal(dict(c.active.nl), settings)
    return f"{c.effect.name}: {why}" if why else None

