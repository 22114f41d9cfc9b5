"""A pair claimed together is reported together: one unit in the order of shares, judged as a pair.

Measured on the demo campaign with the trained FED-LSTM (30 Nov 2026): the selection claims
``leg_weight_buoyancy`` + ``link_weight_buoyancy`` as a pair (held-out t 4.3; alone -3.1 and 1.4). The
report then counted the first member alone and printed "adding leg_weight_buoyancy removes 1 % of the
held-out fz error (held-out t = -3.6)" under "Effects claimed": a claim beside the evidence against it.
The order of the shares now moves a pair as one unit, and both members' sentences carry the pair's test.
The held-out errors here are numbers written in the test (what a fit's held-out rows sum to), not fits.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from workbench.diagnose.loop_claims import _ordered, _units


def _step(name: str, partner: str | None = None):
    return SimpleNamespace(candidate=SimpleNamespace(effect=SimpleNamespace(name=name)), partner=partner)


def test_a_pair_is_one_unit_in_selection_order_and_a_lone_effect_stays_alone():
    steps = [_step("drift"), _step("leg", "link"), _step("link", "leg"), _step("servo")]
    assert _units(steps) == [("drift",), ("leg", "link"), ("servo",)]
    # a partner that the final check dropped is no unit member
    assert _units([_step("leg", "link"), _step("servo")]) == [("leg",), ("servo",)]


def _fit(mse: list[float]):
    """Something with a fit's held-out rows: one block per channel value, one tick each."""
    sse = np.diag(mse)  # block b holds channel b's squared error
    return SimpleNamespace(sse_block_c=sse, grams=SimpleNamespace(heldout=np.ones(len(mse), bool),
                                                                  n=np.ones(len(mse))))


def test_the_pair_moves_as_one_when_it_only_helps_after_a_later_effect():
    base = _fit([4.0, 4.0])
    # held-out MSE of each prefix (members in any order): the pair alone does nothing, servo alone helps,
    # the pair beside the servo helps
    table = {frozenset(): [4.0, 4.0], frozenset({"servo"}): [2.0, 2.0],
             frozenset({"leg", "link"}): [4.5, 4.5], frozenset({"leg", "link", "servo"}): [1.0, 1.0],
             frozenset({"leg"}): [5.0, 5.0], frozenset({"leg", "servo"}): [2.5, 2.5]}

    def prefix_fit(members):
        return _fit(table[frozenset(members)])

    order = _ordered([("leg", "link"), ("servo",)], base, prefix_fit)
    assert order == [("servo",), ("leg", "link")]
    # every unit's share is positive in that order
    prev = base
    for i in range(len(order)):
        f = prefix_fit([n for u in order[: i + 1] for n in u])
        assert np.all(np.diag(f.sse_block_c) < np.diag(prev.sse_block_c))
        prev = f


def test_an_order_with_positive_shares_is_kept():
    base = _fit([4.0, 4.0])
    table = {frozenset({"leg", "link"}): [3.0, 3.0], frozenset({"leg", "link", "servo"}): [1.0, 1.0]}
    order = _ordered([("leg", "link"), ("servo",)], base, lambda m: _fit(table[frozenset(m)]))
    assert order == [("leg", "link"), ("servo",)]
