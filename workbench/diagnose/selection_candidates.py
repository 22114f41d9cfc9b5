"""The candidates of one selection step: every remaining effect fitted beside the chosen ones.

Linear effects are fitted alone and in pairs from one set of block sums; effects with searched
parameters through :func:`~workbench.diagnose.selection_search.search` (tones at each of the
strongest residual lines). Prunable effects (crosstalk, drift) keep only their significant
entries (:func:`prune`), an implausible alias of a plausible entry going first.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from workbench.diagnose import lsq
from workbench.diagnose.chain import Active
from workbench.diagnose.effects.base import Effect
from workbench.diagnose.selection_records import Candidate, SelectionSettings
from workbench.diagnose.selection_search import search, snap


def candidates(s: SelectionSettings, problem, config, coefs, names, remaining, current, peaks_of, last_nl, progress,
               kept_lines: dict | None = None):
    """Every remaining effect fitted beside the chosen ones (linear ones also in pairs; tones at each line).

    A line's effect is tried at the ``max_peaks`` strongest residual lines, and also at any line
    it was acceptable at in an earlier round (``kept_lines``: effect -> frequencies) while the
    residual still shows it: a 4 Hz / 10 % flow tone beside an out-of-library 3.3 Hz vibration was
    acceptable for five rounds while force effects won them, then its line fell to third behind
    the vibration's and a 2.2 Hz one, was never tried again, and was reported as unexplained
    (battery probe 4, EF, measured 30 Nov 2026).
    """
    linear = [e for e in remaining if not e.search and not e.needs_peak]
    cands = _linear_candidates(s, problem, config, coefs, names, linear)
    for e in remaining:
        if e.needs_peak:
            peaks = peaks_of(e, config, current) if peaks_of is not None else []
            for pk in lines_to_try(s, peaks, (kept_lines or {}).get(e.name, ())):
                cands.append(_nonlinear_candidate(s, problem, config, coefs, names, e, pk))
        elif e.search:
            # after the first step, start from the last optimum (the landscape moves little)
            c = _nonlinear_candidate(s, problem, config, coefs, names, e, start=last_nl.get(e.name))
            last_nl[e.name] = dict(c.active.nl)
            cands.append(c)
        if progress:
            progress(e.name)
    return cands


def lines_to_try(s: SelectionSettings, peaks: list, kept=()) -> list:
    """The ``max_peaks`` strongest residual lines, then a line near each ``kept`` frequency not among them."""
    def strength(p):
        return max(p.ratio.values(), default=0.0)

    out = sorted(peaks, key=lambda p: -strength(p))[: s.max_peaks]
    for f0 in kept:
        if any(abs(p.frequency_hz - f0) <= s.tone_window_hz for p in out):
            continue
        near = [p for p in peaks if abs(p.frequency_hz - f0) <= s.tone_window_hz]
        if near:
            out.append(max(near, key=strength))
    return out


def _linear_candidates(s: SelectionSettings, problem, config, coefs, names, effects) -> list[Candidate]:
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
    if s.pairs:
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


def held_at_bounds(problem, gr: lsq.Grams, nm: list[str], group, f: lsq.Fit) -> tuple[list[str], lsq.Fit]:
    """The fit with amplitudes that went past a zero bound of their plausible range held at it.

    Only a fallback: :meth:`~workbench.diagnose.selection.StepwiseSelection._held` tries it
    when no freely fitted candidate can be claimed at a step (held early, the lag's fast share
    stayed 0 to the end on the battery's campaign, and the other effects took its part).

    An effect of several amplitudes, each physically signed (a circulatory lag's slow and fast
    shares, ``ranges`` ``(0, ...)``), may fit one of them slightly past zero where another effect
    has taken part of its signal; refused as implausible, the effect is then lost for the rest of
    the selection although the other amplitudes carry most of it (measured 29 Nov 2026: a 5 %
    fz-from-fy crosstalk planted into the demo campaign, 96 runs, EF; ``wagner_lag`` with
    ``a_fast`` -0.06 and 69 % of the held-out error was refused at every step, the selection
    stopped after six effects with ``c_n90`` 0.24 and the crosstalk unnamed). As a bounded least
    squares does, such an amplitude is held at its bound (its column dropped: the effect's term
    without it) and the rest refitted, one amplitude at a time, while at least one of the effect's
    own amplitudes stays free. Only amplitudes that are canonical parameters themselves (a
    ``ranges`` key equal to the column's name) are held.
    """
    while True:
        co = f.coefs()
        worst, excess = None, 0.0
        for e in group:
            own = [n for n in nm if n.startswith(e.name + ".")]
            if len(own) < 2:
                continue
            for n in own:
                rng = e.ranges.get(n.split(".", 1)[1])
                if rng is None:
                    continue
                past = -co[n] if rng[0] == 0.0 else (co[n] if rng[1] == 0.0 else 0.0)
                if past > excess:
                    worst, excess = n, past
        if worst is None:
            return nm, f
        nm = [n for n in nm if n != worst]
        sub = gr.subset(nm)
        f = lsq.fit(sub, problem.weights, problem.settings.hac_lags)
        f.grams = sub  # type: ignore[attr-defined]


def peak_grid(s: SelectionSettings, effect, f0: float) -> dict[str, tuple]:
    """The search grid of a line's effect: its first searched parameter within ``tone_window_hz`` of ``f0``."""
    hw = s.tone_window_hz
    return {effect.search[0].name: tuple(np.round(np.linspace(f0 - hw, f0 + hw, 9), 4))}


def _nonlinear_candidate(s: SelectionSettings, problem, config, coefs, names, effect, peak=None, start=None) -> Candidate:
    """An effect with searched parameters fitted beside the chosen ones (a tone around ``peak``, others from ``start``)."""
    grids = None
    if effect.needs_peak:
        # the frequency proposed by the evidence is the effect's first searched parameter
        grids = peak_grid(s, effect, peak.frequency_hz)
        start = None
    nl, profile = search(s, problem, config, coefs, names, effect, grids, start=start)
    if getattr(problem, "surrogate_search", False) and effect.stage == "input":
        # an expensive model runs once per input value: values on a 2 % (log) or 0.005 grid
        # recur from step to step, and the model's output for them is still cached
        nl = {p.name: snap(nl[p.name], p) for p in effect.search}
    act = Active(effect, nl)
    cfg = config.with_effect(act)
    nm = names + [f"{effect.name}.{n}" for n in effect.linear_names()]
    # an input effect with an expensive model is screened through the surrogate; only the
    # candidate about to be claimed is refitted with the model itself (select)
    sur = bool(getattr(problem, "surrogate_search", False) and effect.stage == "input")
    f = problem.fit(cfg, coefs, nm, surrogate=sur)
    return Candidate(effect, act, cfg, nm, f, profile=profile, surrogate=sur)


def prune(s: SelectionSettings, problem, cand: Candidate, coefs) -> Candidate:
    """Drop individually insignificant entries of prunable effects (crosstalk, drift) and refit."""
    for e in cand.effects:
        if e.prunable:
            cand = _prune_one(s, problem, cand, e)
    return cand


def _prune_one(s: SelectionSettings, problem, cand: Candidate, e: Effect) -> Candidate:
    """``e``'s entries reduced to the significant ones by backward elimination, refitted (``cand`` if all stay)."""
    own = [n for n in cand.names if n.startswith(e.name + ".")]
    zc = stats.norm.isf(s.prune_alpha / (2 * max(len(own), 1)))
    keep = list(own)
    gr = cand.fit.grams
    # backward elimination: drop the weakest entry and refit until every entry left is significant.
    # An entry outside its plausible range goes first, whatever its z: an alias of a plausible entry
    # in the same channel first (tz = 0.02 fy makes x_fz_tz = 1.5 read as x_fz_fy = 0.03), then the
    # most implausible (a load cell does not read 138 % of another channel: beside a 3 % ty-from-fy
    # crosstalk the misfit guard's ty residual is 0.03 fy, so x_fz_fy's guarded column is what little
    # of fy that residual does not follow, and it read 1.38 with the FED-LSTM as base)
    while len(keep) > 1:
        names = [n for n in cand.names if n not in own] + keep
        f = lsq.fit(gr.subset(names), problem.weights, problem.settings.hac_lags)
        co, se = f.coefs(), f.stderr()
        bad = _implausible_alias(e, gr, keep, co) or _most_implausible(e, keep, co)
        if bad is not None:
            keep.remove(bad)
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


def _outside(e: Effect, n: str, coefs: dict) -> float:
    """How far entry ``n`` (qualified) lies outside ``e``'s plausible range: |value| / the range's reach (0: inside)."""
    short = n.split(".", 1)[1]
    if not e.implausible({short: coefs[n]}):
        return 0.0
    rng = e.range_of(short)  # not None: an implausible value has a range
    return abs(coefs[n]) / max(abs(rng[0]), abs(rng[1]), 1e-300)


def _most_implausible(e: Effect, keep: list[str], coefs: dict) -> str | None:
    """The entry of ``keep`` furthest outside its plausible range (None: all plausible)."""
    far = max(keep, key=lambda n: _outside(e, n, coefs), default=None)
    return far if far is not None and _outside(e, far, coefs) > 0 else None


def _implausible_alias(e: Effect, gr: lsq.Grams, keep: list[str], coefs: dict, collinear: float = 0.95) -> str | None:
    """The most implausible of ``keep`` (qualified names of ``e``'s entries) that aliases a plausible one.

    Two entries alias when their columns in the same channel are nearly proportional (|cosine|
    at least ``collinear`` over the training blocks); only the plausible one of the two is
    physics, the other reads the same signal through a proportional source.
    """
    reach = {n: _outside(e, n, coefs) for n in keep}
    bad = sorted((n for n in keep if reach[n] > 0), key=reach.get, reverse=True)
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
                if m == n or reach[m] > 0 or pos[m] not in cols:
                    continue
                j = cols.index(pos[m])
                if abs(g[i, j]) >= collinear * np.sqrt(max(g[i, i] * g[j, j], 1e-300)):
                    return n
    return None
