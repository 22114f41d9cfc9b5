"""The end of a selection path: joint refinement of the searched values, then effects that no longer earn a place.

:func:`refine` re-searches each effect's nonlinear parameters with the others at their final
values (with the model itself, never its surrogate); :func:`drop_refused` drops an effect whose
refined values are refused or implausible (another effect in disguise); :func:`drop_unsupported` drops
an effect whose own evidence check fails at its refined values; :func:`backward_check`
drops, weakest first, an effect the held-out test no longer supports once the others are final.
"""

from __future__ import annotations

import numpy as np

from workbench.diagnose.chain import Active
from workbench.diagnose.problem import fit_settled
from workbench.diagnose.selection_candidates import peak_grid, prune
from workbench.diagnose.selection_claims import (
    crossfit_applies,
    telling_blocks,
    variant_correction,
    variant_fits,
)
from workbench.diagnose.selection_judge import crossfit_judge, judge
from workbench.diagnose.selection_records import Candidate, SelectionSettings
from workbench.diagnose.selection_search import parabola, search


def refine(s: SelectionSettings, problem, config, coefs, names, current):
    """Re-search each nonlinear parameter with the others at their final values, in rounds until they settle.

    Always with the model itself (no lagged-output surrogate) and the whole design (no effect's faster
    search criterion): these are the reported values. One effect with searched values is exact in
    one round (its linear terms are refitted at every evaluation). Two or more are searched one at a
    time, which settles slowly where they trade off: with the EF as base, one round left a 40 ms dead
    time beside a 4.5 Hz, zeta 0.08 mount mode at 36 ms and zeta 0.117; a second round moved them to
    39 ms and 0.094 (training error 3.7 % lower), and further rounds went on along the ridge past the
    truth (0.077, 0.064, 0.055; 41, 43, 44 ms), each lowering the error less (measured 30 Nov 2026):
    the base model's misfit, not the data's noise, sets where it ends. So up to
    ``refine_rounds`` rounds run while a value moves more than ``REFINE_MOVE`` (log units, or that share
    of the bounds for a parameter searched on a linear scale); values still moving after the last
    round did not settle, and the effects that moved get a note the diagnosis reports as not converged.
    """
    searched = [a.name for a in config.actives if a.effect.search]
    notes = problem.search_notes  # the diagnosis reports the claimed effects' unconverged final searches
    config, current = _refine_round(s, problem, config, coefs, names, notes)
    moved: dict[str, str] = {}
    for _ in range(1, max(1, s.refine_rounds) if len(searched) > 1 else 1):
        before = config
        config, current = _refine_round(s, problem, config, current.coefs(), names, notes)
        moved = _round_moves(before, config)
        if not moved:
            break
    for name, text in moved.items():
        partners = ", ".join(n for n in searched if n != name)
        notes[name] = (f"its values still moved in the last of {s.refine_rounds} refinement rounds ({text}): "
                       f"they trade off with {partners}")
    return config, current


#: a searched value that moves less than this in a refinement round has settled: in log units (0.02 is 2 %)
#: for a parameter searched on a log scale, as a share of its bounds for one searched on a linear scale
REFINE_MOVE = 0.02


def _round_moves(before, after) -> dict[str, str]:
    """Per effect, what one refinement round moved beyond ``REFINE_MOVE`` ('name old -> new, ...')."""
    was = {a.name: a for a in before.actives}
    out = {}
    for a in after.actives:
        if not a.effect.search or a.name not in was:
            continue
        moves = []
        for p in a.effect.search:
            old, new = float(was[a.name].nl.get(p.name, np.nan)), float(a.nl.get(p.name, np.nan))
            if p.log and old > 0 and new > 0:
                far = abs(np.log(new / old)) > REFINE_MOVE
            else:
                far = abs(new - old) > REFINE_MOVE * (p.bounds[1] - p.bounds[0])
            if far:
                moves.append(f"{p.name} {old:.3g} -> {new:.3g}")
        if moves:
            out[a.name] = ", ".join(moves)
    return out


def _refine_round(s: SelectionSettings, problem, config, coefs, names, notes: dict):
    """One round of :func:`refine`: each searched effect in turn, then the fit; returns (config, fit)."""
    surrogate = getattr(problem, "surrogate_search", False)
    problem.surrogate_search = False
    try:
        for a in list(config.actives):
            if not a.effect.search:
                continue
            rest = config.without(a.name)
            profile: dict = {}
            if surrogate and a.effect.stage == "input":
                # the surrogate's optimum is right to first order: a parabola through three
                # evaluations of the model itself finishes its first searched parameter (each
                # costs a full model run; a shape parameter keeps the surrogate's value)
                nl = parabola(problem, rest, coefs, names, a.effect, dict(a.nl))
            elif a.effect.lookahead:
                # a delay's optimum moves as the force effects come in, and a warm start from an
                # early step can sit in its old basin (a dead time found as a short pure lag):
                # its whole grid is searched again, the current values added to it
                grids = {p.name: tuple(sorted({*p.grid, float(a.nl[p.name])})) for p in a.effect.search}
                nl, profile = search(s, problem, rest, coefs, names, a.effect, grids=grids, fast=False)
            elif a.effect.needs_peak:
                # a line's effect stays on its line: searched again within the window it was proposed in.
                # Warm-started (+-20 %), the FED-LSTM's 2.00 Hz flow tone on the demo campaign moved to
                # 1.80 Hz, a harmonic of every gait (0.3, 0.45, 0.6 Hz), where its per-run fit took in the
                # stroke's misfit, its off-peak fits gained as much, and the backward check dropped it
                first = a.effect.search[0].name
                grids = peak_grid(s, a.effect, float(a.nl[first]))
                grids[first] = tuple(sorted({*grids[first], float(a.nl[first])}))
                nl, profile = search(s, problem, rest, coefs, names, a.effect, grids=grids, fast=False)
            else:
                nl, profile = search(s, problem, rest, coefs, names, a.effect, start=dict(a.nl), fast=False)
            config = rest.with_effect(Active(a.effect, nl))
            if profile.get("note"):
                notes[a.name] = profile["note"]
            else:
                notes.pop(a.name, None)
    finally:
        problem.surrogate_search = surrogate
    return config, problem.fit(config, coefs, names)


def _dropped_row(a: Active, note: str, test: dict | None = None, max_gain: float = 0.0, digits: int = 3) -> dict:
    """The selection record's row for an effect dropped at the end (its values in the label; its test, if any)."""
    label = ", ".join(f"{k}={v:.{digits}g}" for k, v in a.nl.items())
    test = test or {"t": 0.0, "p": 1.0, "llr": 0.0}
    return {"effect": a.name, "label": f"{a.name}({label})" if label else a.name, "t": float(test["t"]),
            "p": float(test["p"]), "llr": float(test["llr"]), "max_gain": max_gain, "ok": False, "note": note}


def drop_refused(s: SelectionSettings, problem, config, names, current, steps, table):
    """Drop effects whose refined searched values are refused or implausible, refining the rest each time.

    A candidate is judged with the values of its step; the final refinement moves them (a mode
    taken at zeta 0.27 beside an 11 ms lag refined to zeta 0.62 with a 25 ms dead time's
    remainder in it). Such an effect is another effect in disguise and held the others where
    they fitted around it: it goes *before* the others are final, and they are refined again.
    The selection record (``table``) keeps a row saying so.
    """
    table = list(table)
    while True:
        why = {a.name: a.effect.refusal(dict(a.nl), s) or a.effect.implausible(dict(a.nl))
               for a in config.actives if a.effect.search}
        bad = next((a for a in config.actives if why.get(a.name)), None)
        if bad is None:
            return config, names, current, steps, table
        config, names, current, steps = _drop_and_refine(s, problem, config, names, current, steps, table, bad,
                                                         f"dropped after the final refinement: {why[bad.name]}")


def _drop_and_refine(s: SelectionSettings, problem, config, names, current, steps, table: list, a: Active, note: str):
    """``config`` less ``a`` (a row saying ``note`` appended to ``table``), refitted and its searched values refined.

    Returns ``(config, names, current, steps)``.
    """
    table.append(_dropped_row(a, note))
    config = config.without(a.name)
    names = [n for n in names if not n.startswith(a.name + ".")]
    steps = [st for st in steps if st.candidate.effect.name != a.name]
    current = problem.fit(config, current.coefs(), names)
    if any(b.effect.search for b in config.actives):
        config, current = refine(s, problem, config, current.coefs(), names, current)
    return config, names, current, steps


def _checks_evidence(effect) -> bool:
    """Whether ``effect`` has a structural check of its own against the evidence (:meth:`Effect.check`)."""
    from workbench.diagnose.effects.base import Effect

    return type(effect).check is not Effect.check


def drop_unsupported(s: SelectionSettings, problem, config, names, current, steps, table, plausible):
    """Drop effects whose own evidence check fails at their final values, refining the rest each time.

    An effect with a structural check (:meth:`Effect.check`: a mount mode must ring in the residual
    without it, a flow tone must be absent at zero flow) passed it at its step with that step's
    values; the final refinement may move them where the evidence no longer holds. Measured (2 Dec
    2026, EF, a 3 % tz-from-fx crosstalk and a 5 Hz vibration in tz planted): a mode was claimed at
    step 2 at 4.90 Hz, zeta 0.040, where the vibration's line made the residual "ring", and the
    refinement, with the force effects in, moved it to 6.78 Hz, zeta 0.012, a notch on residual power
    where nothing rang; the force effects fitted around it (c_n90 1.10 against 1.17, friction refused).
    The check is ``plausible(candidate, config without it, its fit)``, as at a step; the selection
    record keeps a row for each effect dropped. ``plausible`` None: nothing is checked.
    """
    table = list(table)
    while plausible is not None:
        failed = _first_unsupported(problem, config, names, current, plausible)
        if failed is None:
            break
        a, why = failed
        config, names, current, steps = _drop_and_refine(s, problem, config, names, current, steps, table, a,
                                                         f"dropped after the final refinement: at its final values {why}")
    return config, names, current, steps, table


def _first_unsupported(problem, config, names, current, plausible) -> tuple[Active, str] | None:
    """The first effect of ``config`` whose own check fails beside the others (with why), None when all pass."""
    for a in config.actives:
        if not _checks_evidence(a.effect):
            continue
        rest = config.without(a.name)
        rnames = [n for n in names if not n.startswith(a.name + ".")]
        ok, why = plausible(Candidate(a.effect, a, config, names, current), rest,
                            problem.fit(rest, current.coefs(), rnames))
        if not ok:
            return a, why
    return None


def profiled(s: SelectionSettings, problem, config, a: Active, coefs: dict, rnames: list[str]):
    """``config`` without ``a``, its timing partners' searched values searched again without it.

    A delay and a low-pass mode trade off (below the mode, its damping's phase is a delay's:
    a 4.5 Hz, zeta 0.08 mount mode was measured at zeta 0.035 with a 6.9 ms servo lag beside
    it). Judged with the mode held at the damping it took beside the lag, the lag looks needed;
    the likelihood ratio that tests it compares the best fit without it, the mode's values
    searched again (a profile likelihood). A partner whose values searched without ``a`` would be
    refused or implausible (a mode stretched to zeta 0.9 to stand in for a 60 ms delay) keeps its
    values: the fit without ``a`` must be one the selection could claim. Other effects, and ``a``
    when it sets no timing, keep their values.
    """
    rest = config.without(a.name)
    if not a.effect.timing:
        return rest
    for b in [b for b in rest.actives if b.effect.timing and b.effect.search]:
        others = rest.without(b.name)
        nl, _ = search(s, problem, others, coefs, rnames, b.effect, start=dict(b.nl), fast=False)
        if not (b.effect.refusal(dict(nl), s) or b.effect.implausible(dict(nl))):
            rest = others.with_effect(Active(b.effect, nl))
    return rest


def _moved(config, rest) -> str:
    """The partners' values the profile moved, for a dropped effect's row ('' when none moved)."""
    was = config.nl_values()
    moved = [f"{k} {was[k]:.3g} -> {v:.3g}" for k, v in rest.nl_values().items()
             if k in was and abs(v - was[k]) > 1e-9 * max(abs(was[k]), 1.0)]
    return f" (searched again without it: {', '.join(moved)}; they trade off)" if moved else ""


def backward_check(s: SelectionSettings, problem, config, names, current, steps, table: list | None = None):
    """Drop effects that no longer earn their place once the others are final (collinear partners).

    Each effect, weakest first, is removed and the rest refitted; if the held-out test no
    longer clears the claim criteria for putting it back, it goes, and the selection record
    (``table``, when given) keeps a row saying so. The last claim left is judged too (against
    the base model alone): an effect claimed as one of a pair earned its place with its partner,
    and once the partner has gone it must earn it alone. Until 1 Dec 2026 the check stopped at
    one effect: with the FED-LSTM and a 25 ms dead time, `normal_force_law` + `loadcell_crosstalk`
    were claimed as a pair (held-out t 4.2), the crosstalk was dropped here (p 0.011), and
    `normal_force_law` stayed claimed alone at p 0.038, far from its level.
    """
    hac = problem.settings.hac_lags
    # every fit judged here at its fixed point (a crosstalk's passes may settle slowly: problem.fit_settled)
    current = fit_settled(problem, config, current.coefs(), names)
    changed = True
    while changed and config.actives:
        changed = False
        level = s.alpha / len(config.actives)
        verdicts = []
        for a in config.actives:
            rnames = [n for n in names if not n.startswith(a.name + ".")]
            rest = profiled(s, problem, config, a, current.coefs(), rnames)
            f, after = fit_settled(problem, rest, current.coefs(), rnames), current
            jn = a.effect.judged_as(dict(a.nl))
            variants, telling = [], None
            if jn is None and len(a.effect.null_variants(dict(a.nl))) >= 3:
                # a per-run fit (a tone's phases): judged against its off-peak variants, as at its step
                variants = variant_fits(problem, a.effect, config, dict(a.nl), names, current.coefs())
                telling = telling_blocks(problem, a.effect, dict(a.nl), after.grams)
            elif jn is not None:
                # judged as at its step: beside its nuisance, against the nuisance alone
                own = [n for n in names if n.startswith(a.name + ".")]
                jnames = names + [f"{a.name}.{n}" for n in a.effect.judging_names(jn, own)]
                after = fit_settled(problem, config.with_effect(Active(a.effect, jn)), current.coefs(), jnames)
                nulls = a.effect.null_variants(jn)
                if nulls:
                    f = fit_settled(problem, config.with_effect(Active(a.effect, nulls[0])), current.coefs(), jnames)
            if crossfit_applies(s, a.effect, f, after, variants):
                # judged cross-fitted, as at its step (selection_claims.crossfit_plan)
                test, gain = crossfit_judge(f, after, problem.block_folds(after.grams, s.judge_folds), problem.weights,
                                            hac, variants, telling)
            else:
                corr, null_sse = variant_correction(variants, f)
                test, gain = judge(f, after, after.grams, hac, corr, null_sse, telling)
            verdicts.append((test["llr"], a, rnames, test, gain, rest))
        llr, a, rnames, test, gain, rest = min(verdicts, key=lambda v: v[0])
        if test["p"] >= level or a.effect.practical_gain(gain).max() < s.min_gain:
            if table is not None:
                beside = "alone, against the base model" if len(config.actives) == 1 else "beside the others' final values"
                table.append(_dropped_row(
                    a, f"claimed at its step, dropped in the final check: {beside}"
                       f"{_moved(config, rest)} p={test['p']:.2g} (level {level:.2g}), held-out gain {gain.max():.1%}",
                    test, float(gain.max()), digits=4))
            # the partners keep the values searched without it (the profile the test was judged on)
            config = rest
            names = rnames
            current = fit_settled(problem, config, current.coefs(), names)
            steps = [st for st in steps if st.candidate.effect.name != a.name]
            changed = True
    return config, names, current, steps


def _live(coefs: dict, names: list[str], own: tuple[str, ...]) -> dict:
    """``coefs`` without the entries of prunable effects that are no longer fitted.

    The current values reach the effects' columns (a crosstalk's guard takes the other channels'
    residuals after its own entries); a pruned entry's last value would still act there.
    """
    kept = set(names)
    return {k: v for k, v in coefs.items() if not k.startswith(own) or k in kept}


def _pruned(s: SelectionSettings, problem, config, names, current, prunable, own):
    """Prune every prunable effect's entries on training runs; refit (without the dropped entries) when any went."""
    for a in prunable:
        cand = prune(s, problem, Candidate(a.effect, a, config, names, current), _live(current.coefs(), names, own))
        if cand.names != names:
            names = cand.names
            current = problem.fit(config, _live(current.coefs(), names, own), names)
    return names, current


def settle(s: SelectionSettings, problem, config, names, current, rounds: int = 6, tol: float = 1e-4):
    """Prune the entries of prunable effects (crosstalk, drift), refit until they settle, then prune them again.

    An effect whose columns depend on its own current values (a crosstalk's misfit guard takes
    the other channels' residuals after the crosstalk, :meth:`LoadcellCrosstalk._residual`)
    reaches its fixed point by refits from its last values; its entries were chosen at its step
    beside residuals that still held the crosstalk itself, so they are chosen again at the
    fixed point by the same backward elimination (:func:`~workbench.diagnose.selection_candidates.prune`).

    Returns ``(names, fit, change)``: ``change`` is the entries' largest change in the last refit,
    at most ``tol`` when they settled (the caller records it in the selection table otherwise).
    """
    prunable = [a for a in config.actives if a.effect.prunable]
    if not prunable:
        return names, current, 0.0
    own = tuple(f"{a.name}." for a in prunable)
    # entries insignificant at the step's values go first: a spurious entry into a quiet channel moves that
    # channel's guard residual by a large share of itself (x_ty_fy 0.0003 N m/N beside a 5 % fz-from-fy
    # crosstalk, FED-LSTM: x_fz_fy swung between 0.013 and 0.059 over six refits and was reported at 0.040)
    names, current = _pruned(s, problem, config, names, current, prunable, own)
    change = np.inf
    for _ in range(3):
        current, change = _refitted(problem, config, names, current, own, rounds, tol)
        kept, current = _pruned(s, problem, config, names, current, prunable, own)
        if kept == names:
            break
        # entries went at the fixed point: the rest settle again without them (with both a 0.0008 ty-from-fy
        # and the 5 % fz-from-fy entry the refits swung; the fz entry alone is its own fixed point)
        names = kept
    return names, current, change


def _refitted(problem, config, names, current, own: tuple[str, ...], rounds: int, tol: float):
    """Refit from the current values until the prunable entries change by less than ``tol``: (fit, last change)."""
    change = np.inf
    for _ in range(rounds):
        new = problem.fit(config, _live(current.coefs(), names, own), names)
        old, co = current.coefs(), new.coefs()
        current = new
        change = max((abs(co[k] - old.get(k, 0.0)) for k in co if k.startswith(own)), default=0.0)
        if change < tol:
            break
    return current, change
