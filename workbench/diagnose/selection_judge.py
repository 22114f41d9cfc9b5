"""Held-out significance of one fit against another: the block log-likelihood gain and its tests.

:func:`judge` tests ``after`` against ``before`` on the held-out blocks: by a one-sided t-test
with a Newey-West variance over neighbouring blocks, or, for a per-run nuisance fit with off-peak
variants, against the variants' own spread run by run (:func:`_null_spread_test`: F ratios combined
by Fisher's method). :func:`crossfit_judge` makes the same test with every parameter set held out once
(for effects that ask for it, ``Effect.crossfit``). The step's Bonferroni levels and the claim criteria are in
:mod:`workbench.diagnose.selection_claims`.
"""

from __future__ import annotations

import dataclasses
import types

import numpy as np
from scipy import stats

from workbench.diagnose import lsq


def block_llr(before: lsq.Fit, after: lsq.Fit, gr: lsq.Grams) -> np.ndarray:
    """Held-out log-likelihood gain per block: sum over channels of n/2 log(SSE_before / SSE_after)."""
    sb = np.maximum(before.sse_block_c, 1e-300)
    sa = np.maximum(after.sse_block_c, 1e-300)
    return 0.5 * gr.n[:, None] * np.log(sb / sa)


def judge(before: lsq.Fit, after: lsq.Fit, gr: lsq.Grams, hac_lags: int, correction: np.ndarray | None = None,
          null_sse_c: np.ndarray | None = None, telling: np.ndarray | None = None):
    """Held-out test of ``after`` against ``before``: t, p, llr and per-channel relative MSE reduction.

    ``correction``: per block, what the same per-run fit gains at off-peak variants, ``(k, nb)`` (or
    their mean, ``(nb,)``). The gain beyond their mean is tested; with ``k >= 3`` variants against
    their spread (:func:`_null_spread_test`), otherwise by the blocks' own scatter.
    ``null_sse_c``: the variants' squared error per block and channel, ``(k, nb, channels)``. With
    ``k >= 3`` the per-channel gain is then what ``after`` removes beyond the variants' mean
    (:func:`_gain_beyond_nulls`), the same comparison the test makes, over the blocks whose runs can
    tell the effect from the misfit (``telling``, per block; None: all held-out blocks).
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
    if nulls is not None and len(nulls) >= 3 and null_sse_c is not None:
        h_gain = gr.heldout if telling is None else gr.heldout & np.asarray(telling, bool)
        gain_c = _gain_beyond_nulls(before, after, np.asarray(null_sse_c), h_gain)
    elif correction is not None:
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


def crossfit_judge(before: lsq.Fit, after: lsq.Fit, fold: np.ndarray, weights: np.ndarray, hac_lags: int,
                   variants: list[lsq.Fit] = (), telling: np.ndarray | None = None):
    """:func:`judge` of ``after`` against ``before`` cross-fitted: each fold's blocks predicted by a fit on the others.

    ``fold``: per block, its fold (0: the split's held-out sets, whose blocks keep the fits as
    given; :func:`workbench.diagnose.data.crossfit_folds`). Both fits are linear in their columns,
    so each fold is one more solve of the same block sums. The test then counts every block of
    the campaign, not only the held-out sets': measured with the FED-LSTM on a re-measured demo
    campaign (96 runs, 24 sets, 8 held out) with a 5 % fz-from-fy crosstalk planted, the split's
    held-out runs gave t 2.4 (p 0.0087, under the level) where three folds give t 10.8-12.1; on
    the clean copy t -4.3 to 0.0 (``benchmarks/diagnose_crosstalk_judge.py``). The returned ``llr`` is the cross-fitted gain scaled to the
    held-out share of the blocks (comparable with the split's gains of the other candidates of
    a step, which the selection ranks by it); ``llr_crossfit`` is the whole gain.

    ``variants``: a per-run fit's off-peak variants (a tone's phase in each run), cross-fitted
    alike; ``after`` is then tested against their spread run by run over every run, as
    :func:`judge` does over the held-out ones (``telling``: per block, the runs that can tell the
    effect). Per-run columns are fitted within their run wherever it falls, so only the shared
    coefficients change between folds; the variants' in-run gain on the residual's own spectrum is
    the null either way.
    """
    gr = after.grams
    fold = np.asarray(fold, int)
    every = dataclasses.replace(gr, heldout=np.ones_like(gr.heldout))
    sb = types.SimpleNamespace(sse_block_c=crossfit_sse(before, fold, weights, hac_lags))
    corr = null_sse = None
    if len(variants):
        null_sse = np.array([crossfit_sse(v, fold, weights, hac_lags) for v in variants])
        corr = np.array([block_llr(sb, types.SimpleNamespace(sse_block_c=v), gr).sum(axis=1) for v in null_sse])
    test, gain_c = judge(sb, types.SimpleNamespace(sse_block_c=crossfit_sse(after, fold, weights, hac_lags)),
                         every, hac_lags, corr, null_sse, telling)
    share = float(np.mean(gr.heldout)) if len(gr.heldout) else 0.0
    folds = int(len(np.unique(fold)))
    return {**test, "llr_crossfit": test["llr"], "llr": test["llr"] * share, "folds": folds}, gain_c


def crossfit_sse(fit: lsq.Fit, fold: np.ndarray, weights: np.ndarray, hac_lags: int) -> np.ndarray:
    """``fit``'s squared error per block and channel, each fold's blocks (but fold 0's) refitted on the other blocks."""
    sse = fit.sse_block_c.copy()
    for k in np.unique(fold[fold > 0]):
        m = fold == k
        sse[m] = lsq.fit(dataclasses.replace(fit.grams, heldout=m), weights, hac_lags).sse_block_c[m]
    return sse


def _gain_beyond_nulls(before: lsq.Fit, after: lsq.Fit, null_sse_c: np.ndarray, heldout: np.ndarray) -> np.ndarray:
    """Per channel, the share of ``before``'s held-out MSE that ``after`` removes beyond its off-peak variants' mean.

    A per-run fit (a tone's phase in each run) moves the shared coefficients too; in runs where that
    costs more than the fit gains, the variants lose as much as the fit at the proposed value, so a
    plain held-out gain would charge the nuisance's cost to the effect. What the variants leave, less
    what the fit leaves, is the effect's own share (not clipped: negative where the fit loses to them).
    ``heldout``: the blocks counted (the held-out blocks of the runs that can tell the effect).
    """
    sb = before.sse_block_c[heldout].sum(axis=0)
    sa = after.sse_block_c[heldout].sum(axis=0)
    sn = null_sse_c[:, heldout].sum(axis=1).mean(axis=0)
    return np.where(sb > 0, (sn - sa) / np.maximum(sb, 1e-300), 0.0)


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


def heldout_mse(f: lsq.Fit) -> np.ndarray:
    """Held-out mean squared error per channel of a fit."""
    h = f.grams.heldout
    return f.sse_block_c[h].sum(axis=0) / max(f.grams.n[h].sum(), 1)

