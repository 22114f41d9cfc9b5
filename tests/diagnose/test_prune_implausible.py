"""Pruning a crosstalk candidate: an entry outside its plausible range goes first, alias or not.

Measured with the FED-LSTM as base on the battery's rich tunnel (probe case ``xt_ty_from_fy_3pc``): beside
a 3 % ty-from-fy crosstalk the misfit guard's ty residual is 0.03 fy, so the guarded column of
``x_fz_fy`` is what little of fy that residual does not follow, and it read 1.38 (t 38.7). The entry
was significant and its column aliased no plausible one, so the candidate kept it and was refused as
implausible: the planted crosstalk went unnamed. Here the block sums are made by the test: one reading
channel, a plausible entry of 0.03 and an independent entry of 1.4 (a load cell does not read 140 % of
another channel), both far above the noise.
"""

from __future__ import annotations

import types

import numpy as np

from workbench.diagnose import lsq
from workbench.diagnose.chain import Active, Configuration
from workbench.diagnose.effects.crosstalk import LoadcellCrosstalk
from workbench.diagnose.selection_candidates import prune
from workbench.diagnose.selection_records import Candidate, SelectionSettings

FZ, FY, TX = 2, 1, 3


def _grams(rng, true: dict[str, float], n_blocks: int = 60, ticks: int = 200) -> lsq.Grams:
    """Block sums of the fz channel for the entries ``true`` (name -> value), independent sources, unit noise."""
    names = [f"loadcell_crosstalk.{n}" for n in true]
    k = len(names)
    g, b, yy = np.zeros((n_blocks, k, k)), np.zeros((n_blocks, k)), np.zeros((n_blocks, 6))
    for i in range(n_blocks):
        x = rng.normal(size=(ticks, k)) * 10.0
        r = x @ np.array(list(true.values())) + rng.normal(size=ticks)
        g[i], b[i], yy[i, FZ] = x.T @ x, x.T @ r, r @ r
    empty = (np.zeros((n_blocks, 0, 0)), np.zeros((n_blocks, 0)))
    chan_cols = [np.arange(k) if c == FZ else np.array([], int) for c in range(6)]
    return lsq.Grams(names, chan_cols, [g if c == FZ else empty[0] for c in range(6)],
                     [b if c == FZ else empty[1] for c in range(6)], yy, np.full(n_blocks, ticks),
                     np.repeat(np.arange(n_blocks // 5), 5), np.tile(np.arange(5), n_blocks // 5),
                     np.arange(n_blocks) >= 0.7 * n_blocks, [])


def _candidate(gr: lsq.Grams, problem) -> Candidate:
    effect = LoadcellCrosstalk(pairs=[(FZ, FY), (FZ, TX)])
    f = lsq.fit(gr, problem.weights, problem.settings.hac_lags)
    f.grams = gr
    return Candidate(effect, Active(effect, {}), Configuration([Active(effect, {})]), list(gr.names), f)


def test_an_implausible_entry_that_aliases_nothing_is_pruned_first():
    rng = np.random.default_rng(3)
    problem = types.SimpleNamespace(weights=np.ones(6), settings=types.SimpleNamespace(hac_lags=2))
    gr = _grams(rng, {"x_fz_fy": 0.03, "x_fz_tx": 1.4})
    cand = _candidate(gr, problem)
    co = cand.fit.coefs()
    se = cand.fit.stderr()
    # both entries are far above the noise, and their columns are independent (no alias)
    assert abs(co["loadcell_crosstalk.x_fz_tx"]) / se["loadcell_crosstalk.x_fz_tx"] > 50
    assert abs(co["loadcell_crosstalk.x_fz_fy"]) / se["loadcell_crosstalk.x_fz_fy"] > 10
    out = prune(SelectionSettings(), problem, cand, {})
    assert out.names == ["loadcell_crosstalk.x_fz_fy"], out.names
    # the plausible entry is refitted alone: the dropped source's signal is noise to it, it stays near 0.03
    assert abs(out.fit.coefs()["loadcell_crosstalk.x_fz_fy"] - 0.03) < 0.01


def test_plausible_significant_entries_are_kept():
    rng = np.random.default_rng(4)
    problem = types.SimpleNamespace(weights=np.ones(6), settings=types.SimpleNamespace(hac_lags=2))
    cand = _candidate(_grams(rng, {"x_fz_fy": 0.03, "x_fz_tx": 0.1}), problem)
    out = prune(SelectionSettings(), problem, cand, {})
    assert sorted(out.names) == ["loadcell_crosstalk.x_fz_fy", "loadcell_crosstalk.x_fz_tx"]
