"""From the selected configuration to the claims: effect reports, their intervals, and what is left.

After selection, each claimed effect gets its canonical parameters with standard errors (nonlinear
ones through Gauss-Newton columns), its sequential share of the held-out error and its evidence
sentence (:func:`_effect_reports`); claims whose final intervals span zero are dropped, weakest
first, with a refit (:func:`_enforce_claims`); and the residual structure no claim explains is
listed (:func:`_unexplained`).
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from workbench.diagnose import lsq
from workbench.diagnose.chain import Active, Configuration, Design
from workbench.diagnose.evidence_base import Evidence
from workbench.diagnose.loop_results import CHANNELS, EffectReport, Unexplained
from workbench.diagnose.loop_settings import DiagnoseSettings
from workbench.diagnose.problem import Problem, fit_settled
from workbench.diagnose.selection import judge
from workbench.diagnose.selection_claims import crossfit_applies
from workbench.diagnose.selection_judge import crossfit_judge, heldout_mse


def _heldout_mse(runs) -> dict[str, float]:
    e = np.concatenate([r.resid[r.fit] for r in runs if r.heldout])
    return {c: float((e[:, i] ** 2).mean()) for i, c in enumerate(CHANNELS)}


def _nl_stderr(problem: Problem, config: Configuration, fit: lsq.Fit, names: list[str]) -> dict[str, float]:
    """Standard errors of nonlinear parameters: Gauss-Newton columns d(prediction)/d(param) in the sandwich fit."""
    out: dict[str, float] = {}
    coefs = fit.coefs()
    for a in config.actives:
        for p, v in a.nl.items():
            h = max(abs(v) * 0.02, 1e-4)
            parts = []
            for rs, blocks in problem.sets("all"):
                preds = []
                for sign in (1, -1):
                    cfg = config.with_effect(Active(a.effect, {**a.nl, p: v + sign * h}))
                    d = problem.design(rs, cfg, coefs, names)
                    preds.append(d.predict(coefs, _local_rows(fit, d, rs)))
                d0 = problem.design(rs, config, coefs, names)
                jac = (preds[0] - preds[1]) / (2 * h)
                dj = Design(d0.base, d0.names + ["__jac__"], d0.cols + [jac], d0.support + [np.ones(6, bool)],
                            d0.local_names, d0.local)
                parts.append(lsq.accumulate(dj, rs, blocks, names + ["__jac__"]))
            gr = lsq.concat(parts)
            # the Jacobian's coefficient is the parameter's Gauss-Newton correction; its sandwich
            # error, with the linear terms refitted beside it, is the parameter's profiled error
            f = lsq.fit(gr, problem.weights, problem.settings.hac_lags)
            out[f"{a.name}.{p}"] = float(np.sqrt(max(f.cov[-1, -1], 0.0)))
    return out


def _local_rows(fit: lsq.Fit, d: Design, rs) -> dict[str, np.ndarray] | None:
    if not d.local_names or not fit.local:
        return None
    m = len(d.local_names)
    vals = np.array([fit.local.get(int(i), np.zeros(m)) for i in rs.index])
    return {n: vals[:, j] for j, n in enumerate(d.local_names)}


def _local_table(fit: lsq.Fit, grams: lsq.Grams, campaign, effect: str) -> dict[str, tuple] | None:
    """One effect's per-run columns: (values, information, flow speed) over runs, by local name (None: none)."""
    if not grams.local_names or not fit.local:
        return None
    runs = sorted(fit.local)
    out = {}
    for j, n in enumerate(grams.local_names):
        owner, local = n.split(".", 1)
        if owner != effect:
            continue
        vals = np.array([fit.local[r][j] for r in runs])
        info = np.array([fit.local_info[r][j] for r in runs])
        flows = np.array([campaign.runs[r].flow_speed_mps for r in runs])
        out[local] = (vals, info, flows)
    return out or None


def _gain(before: lsq.Fit, after: lsq.Fit, hac: int, problem: Problem | None = None, effects=(),
          s: DiagnoseSettings | None = None) -> tuple[dict, np.ndarray]:
    """The held-out test of ``after`` against ``before``, and the share of each channel's held-out MSE it removes.

    An effect the selection judges cross-fitted (``Effect.crossfit``: every parameter set held out
    once) is reported with that test and its cross-fitted shares, the evidence its claim stood on. Until
    1 Dec 2026 the report took the split's held-out sets alone: the demo diagnosis printed
    ``leg_weight_buoyancy`` at "held-out t = 1.3" (p 0.10), claimed at t 5.4 cross-fitted over 3 folds.
    """
    if problem is not None and s is not None and any(
            crossfit_applies(s.selection, e, before, after) for e in effects):
        return crossfit_judge(before, after, problem.block_folds(after.grams, s.selection.judge_folds),
                              problem.weights, hac)
    test, _ = judge(before, after, after.grams, hac)
    mp, ma = heldout_mse(before), heldout_mse(after)
    return test, np.where(mp > 0, (mp - ma) / np.maximum(mp, 1e-300), 0.0)


def _units(steps) -> list[tuple[str, ...]]:
    """The claimed effects in selection order, a pair claimed together (``Step.partner``) as one unit."""
    names = [st.candidate.effect.name for st in steps]
    partner = {st.candidate.effect.name: st.partner for st in steps}
    units, seen = [], set()
    for n in names:
        if n in seen:
            continue
        p = partner.get(n)
        unit = (n, p) if p in names and p not in seen else (n,)
        seen.update(unit)
        units.append(unit)
    return units


def _ordered(units: list[tuple[str, ...]], base_fit: lsq.Fit, prefix_fit: Callable) -> list[tuple[str, ...]]:
    """``units`` in an order where each one's sequential held-out share is positive, where such an order is near.

    A unit that only helps once a later one is in (a collinear partner) would show a negative share in
    selection order: it moves one place later until every share is positive (at most ``len ** 2`` moves). A
    pair claimed together moves as one: each member alone may not help at all (measured: the FED-LSTM's demo
    diagnosis claims ``leg_weight_buoyancy`` + ``link_weight_buoyancy``, +0.036 N at the web and -0.036 N over
    the links; alone the first reads held-out t -3.1, the pair t 4.3).
    """
    order = list(units)
    for _ in range(len(order) ** 2):
        prev_m = heldout_mse(base_fit)
        moved = False
        for i in range(len(order) - 1):
            m = heldout_mse(prefix_fit([n for u in order[: i + 1] for n in u]))
            if np.mean((prev_m - m) / np.maximum(prev_m, 1e-300)) <= 0:
                order[i], order[i + 1] = order[i + 1], order[i]
                moved = True
                break
            prev_m = m
        if not moved:
            break
    return order


def _params(act: Active, coefs: dict, cov: dict, final: lsq.Fit, campaign) -> tuple[dict, dict, list[str]]:
    """One claimed effect's canonical parameters, their standard errors, and the effect's own notes."""
    name = act.name
    eff_coefs = {k.split(".", 1)[1]: v for k, v in coefs.items() if k.split(".", 1)[0] == name}
    # an amplitude held at its zero bound (selection_candidates.held_at_bounds) is reported as 0
    held = [] if act.effect.prunable else [n for n in act.effect.linear_names() if n not in eff_coefs
                                           and 0.0 in act.effect.ranges.get(n, (None, None))]
    eff_coefs.update({n: 0.0 for n in held})
    eff_cov = {(a.split(".", 1)[1], b.split(".", 1)[1]): v for (a, b), v in cov.items()
               if a.split(".", 1)[0] == name and b.split(".", 1)[0] == name}
    params, se = act.effect.canonical_params(eff_coefs, dict(act.nl), eff_cov,
                                             _local_table(final, final.grams, campaign, name))
    notes = list(act.effect.notes(eff_coefs)) + [f"{n} held at its bound 0 (fitted past it)" for n in held]
    return params, se, notes


def _effect_reports(problem: Problem, result, base_fit: lsq.Fit, mse_before: dict, ev_before: Evidence,
                    s: DiagnoseSettings) -> list[EffectReport]:
    """Canonical parameters, intervals, sequential held-out reductions and evidence of each claimed effect."""
    final = result.fit
    config, names = result.config, result.names
    nl_se = _nl_stderr(problem, config, final, names) if any(a.nl for a in config.actives) else {}
    cov_names = list(final.names)
    cov = {(a, b): float(final.cov[i, j]) for i, a in enumerate(cov_names) for j, b in enumerate(cov_names)}
    cov.update({(k, k): v * v for k, v in nl_se.items()})
    coefs = final.coefs()
    prefix_fits: dict[frozenset, lsq.Fit] = {}

    def prefix_fit(members) -> lsq.Fit:
        key = frozenset(members)
        if key not in prefix_fits:
            part = Configuration([a for a in config.actives if a.name in key])
            prefix_fits[key] = fit_settled(problem, part, coefs, [n for n in names if n.split(".", 1)[0] in key])
        return prefix_fits[key]

    units = _ordered(_units(result.steps), base_fit, prefix_fit)
    # sequential held-out MSE with the final nonlinear values: effect i's share of the error removed
    prev = base_fit
    m0 = heldout_mse(base_fit)
    hac = problem.settings.hac_lags
    reports, done = [], []
    for unit in units:
        # a pair claimed together is judged and described together: each member alone may not help at all
        effects = [a.effect for a in config.actives if a.name in unit]
        joint = _gain(prev, prefix_fit(done + list(unit)), hac, problem, effects, s) if len(unit) > 1 else None
        for name in unit:
            done.append(name)
            f = prefix_fit(done)
            own = [a.effect for a in config.actives if a.name == name]
            test, step_rel = joint or _gain(prev, f, hac, problem, own, s)
            by_ch = np.where(m0 > 0, (heldout_mse(prev) - heldout_mse(f)) / np.maximum(m0, 1e-300), 0.0)
            chans = [c for c, g in zip(CHANNELS, step_rel, strict=False) if g >= s.report.channel_min_gain]
            act = next(a for a in config.actives if a.name == name)
            params, se, notes = _params(act, coefs, cov, final, problem.campaign)
            step = next(st for st in result.steps if st.candidate.effect.name == name)
            best_c = CHANNELS[int(np.argmax(step_rel))]
            reduction = float(by_ch.mean())
            hint = act.effect.hint(ev_before, params)
            alt = f"; {', '.join(step.alternatives)} explained nearly as much" if step.alternatives else ""
            other = next((n for n in unit if n != name), None)
            folds = f", cross-fitted over {test['folds']} folds" if test.get("folds") else ""
            what = (f"adding {name} with {other} (claimed as a pair: together they gain at least "
                    f"{s.selection.pair_margin:g}x what either gains alone) removes" if other else f"adding {name} removes")
            sentence = (f"{hint + '; ' if hint else ''}{what} {step_rel.max():.0%} of the held-out "
                        f"{best_c} error (held-out t = {test['t']:.1f} over {test['n_blocks']} blocks{folds}){alt}.")
            if other is not None:
                notes.append(f"claimed as a pair with {other}, the two together: its own share of the held-out "
                                 f"error ({reduction:+.1%} on average over channels) is counted "
                                 f"{'before' if name == unit[0] else 'beside'} {other}")
            amb = [n for n in step.ambiguous_with if n != name]
            if amb:
                notes.append(f"the held-out data cannot tell {name} from {', '.join(amb)} (the winner's held-out "
                             "gain over each is not significant): the attribution is ambiguous")
            reports.append(EffectReport(name, chans, params, se, sentence, reduction,
                                        {c: float(v) for c, v in zip(CHANNELS, by_ch, strict=False)}, test,
                                        step.alternatives, notes, amb))
            prev = f
    return reports


def _claim_faults(rep: EffectReport, effect, s: DiagnoseSettings) -> str | None:
    """Why a claimed effect may not stand once its final intervals are known (None when it may)."""
    from workbench.diagnose.selection import magnitude_intervals

    spans = magnitude_intervals(rep.params, rep.stderr, s.selection.interval_z, effect.location_params,
                                effect.negligible_of)
    if spans and all(spans.values()):
        bands = sorted({effect.negligible_of(k) for k in spans} - {0.0})
        band = f" or its negligible band (|x| <= {', '.join(f'{b:g}' for b in bands)})" if bands else ""
        return f"every magnitude parameter's 95 % interval spans zero{band} ({', '.join(spans)})"
    return effect.refusal(rep.params, s.selection)


def _enforce_claims(problem: Problem, result, base_fit: lsq.Fit, mse_before: dict, ev_before: Evidence,
                    s: DiagnoseSettings, say: Callable[[str], None]):
    """No claim without evidence: drop claimed effects whose final intervals span zero (weakest first).

    Selection already refuses linear effects whose interval spans zero; searched parameters
    (a lag's time constant, a mode's damping after the final joint refinement) get their
    profiled errors only here. Each drop refits the remaining effects and recomputes every report.
    """
    while True:
        effects = _effect_reports(problem, result, base_fit, mse_before, ev_before, s)
        claimed = {a.name: a.effect for a in result.config.actives}
        faults = {e.name: _claim_faults(e, claimed[e.name], s) for e in effects}
        faults = {k: v for k, v in faults.items() if v}
        if not faults:
            return result, effects
        worst = min((e for e in effects if e.name in faults), key=lambda e: e.heldout_mse_reduction)
        say(f"dropped {worst.name}: {faults[worst.name]}")
        config = result.config.without(worst.name)
        names = [n for n in result.names if n.split(".", 1)[0] != worst.name]
        fit = fit_settled(problem, config, result.fit.coefs(), names)
        steps = [st for st in result.steps if st.candidate.effect.name != worst.name]
        table = list(result.last_table) + [{"effect": worst.name, "label": worst.name, "t": worst.test.get("t", 0.0),
                                            "p": worst.test.get("p", 1.0), "llr": worst.test.get("llr", 0.0),
                                            "max_gain": max(worst.heldout_mse_reduction_by_channel.values(),
                                                            default=0.0), "ok": False,
                                            "note": f"dropped after the final fit: {faults[worst.name]}"}]
        result = dataclasses.replace(result, config=config, names=names, fit=fit, steps=steps, last_table=table)


_AT_REST = {"still": "the rig's own: a pump, a fan, a mount; it is there in still water",
            "flow": "carried by the flow: it is there only where water flows, not in still water",
            "rest": "the rig's own or the flow's: no still-water runs to tell"}


def _where(p) -> str:
    """Where a line is seen, for its unexplained sentence (motion, rest, still water or flow)."""
    if p.at_rest:
        return f"while the leg stands still before its runs ({_AT_REST.get(p.rest_seen, _AT_REST['rest'])})"
    out = "in runs of every gait frequency (locked to nothing the rig does)"
    if p.rest_seen:
        out += f"; at rest before the runs too ({_AT_REST[p.rest_seen]})"
    return out


def _unexplained(ev: Evidence, effects: list[EffectReport], claimed: dict, s: DiagnoseSettings) -> list[Unexplained]:
    """Residual structure left after the claimed effects: lines, stroke-locked misfit, trends."""
    out: list[Unexplained] = []
    lines = [f for e in effects for f in claimed[e.name].explained_frequencies(e.params)]
    # a stroke sideband (f0 +- k gait frequency) goes with its carrier: explained with it, reported with it
    sidebands: dict[float, list] = {}
    for p in ev.peaks:
        if p.sideband_of is not None:
            sidebands.setdefault(p.sideband_of, []).append(p)
    for p in ev.peaks:
        if p.sideband_of is not None or any(abs(p.frequency_hz - f) < p.width_hz for f in lines):
            continue
        best = max(p.ratio, key=p.ratio.get)
        where = _where(p)
        side = sorted(sidebands.get(p.frequency_hz, []), key=lambda q: q.frequency_hz)
        also = "" if not side else (
            "; the stroke modulates it: its sideband" + ("s at " if len(side) > 1 else " at ")
            + ", ".join(f"{q.frequency_hz:.2f}" for q in side)
            + (" Hz lie whole gait frequencies away" if len(side) > 1 else " Hz lies whole gait frequencies away"))
        chans = sorted({c for q in [p, *side] for c in q.channels}, key=CHANNELS.index)
        out.append(Unexplained("narrowband", chans,
                               f"a line at {p.frequency_hz:.2f} Hz stands {p.ratio[best]:.0f}x above the residual "
                               f"floor in {best}, {where}, and no library effect removes it{also}.", p.frequency_hz))
    r = s.report
    # the share of the residual that repeats every stroke beyond what noise puts at the harmonics
    excess = {c: ev.locked_share[c] * max(0.0, 1 - 1 / max(ev.locked_ratio[c], 1e-9)) for c in CHANNELS}
    locked = [c for c in CHANNELS if ev.locked_p[c] < s.evidence.locked_alpha
              and ev.locked_ratio[c] >= s.evidence.locked_ratio and excess[c] >= r.locked_min_share]
    if locked:
        worst = max(locked, key=lambda c: ev.locked_share[c])
        out.append(Unexplained("gait_locked", locked,
                               f"{ev.locked_share[worst]:.0%} of the {worst} residual repeats every stroke "
                               f"({ev.locked_ratio[worst]:.1f}x the power noise would put at the gait harmonics): "
                               "a misfit of the force physics no library effect removes."))
    trend = [c for c in CHANNELS if ev.trend[c]["p"] < s.evidence.trend_alpha
             and ev.trend[c]["share"] >= s.evidence.trend_min_share]
    if trend:
        worst = max(trend, key=lambda c: abs(ev.trend[c]["t"]))
        out.append(Unexplained("trend", trend,
                               f"the {worst} residual drifts by {ev.trend[worst]['slope']:.3g} per second within "
                               f"runs (t = {ev.trend[worst]['t']:.1f}) beyond what the claimed effects removed."))
    return out
