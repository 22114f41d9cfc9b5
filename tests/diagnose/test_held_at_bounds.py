"""A signed amplitude fitted past its zero bound is held there, and the rest refitted (selection_candidates.held_at_bounds).

The data are made here: one channel, y = 0.8 a - 0.05 b + noise over blocks, with the columns a and
b correlated as a circulatory lag's slow and fast parts are. Plain least squares gives b < 0, which
the effect's range (0, 1.5) refuses; held at 0, a alone is fitted, and the effect stays a candidate.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from workbench.diagnose import lsq
from workbench.diagnose.selection_candidates import held_at_bounds


def _grams(cols: dict[str, np.ndarray], y: np.ndarray, n_blocks: int = 40) -> lsq.Grams:
    names = list(cols)
    x = np.column_stack([cols[n] for n in names])
    xb, yb = np.array_split(x, n_blocks), np.array_split(y, n_blocks)
    G = [np.zeros((n_blocks, len(names), len(names))) for _ in range(6)]
    b = [np.zeros((n_blocks, len(names))) for _ in range(6)]
    G[0] = np.stack([xi.T @ xi for xi in xb])
    b[0] = np.stack([xi.T @ yi for xi, yi in zip(xb, yb, strict=True)])
    yy = np.zeros((n_blocks, 6))
    yy[:, 0] = [yi @ yi for yi in yb]
    chan = [np.arange(len(names))] + [np.array([], int)] * 5
    return lsq.Grams(names, chan, G, b, yy, np.array([len(yi) for yi in yb], float), np.arange(n_blocks) // 4,
                     np.arange(n_blocks) % 4, np.arange(n_blocks) % 5 == 0, [])


def _case(b_true: float, ranges: dict):
    rng = np.random.default_rng(3)
    t = np.linspace(0, 60, 6000)
    a = np.sin(2 * np.pi * 0.5 * t)
    bcol = 0.7 * a + 0.3 * np.cos(2 * np.pi * 1.5 * t)  # correlated with a
    y = 0.8 * a + b_true * bcol + 0.05 * rng.standard_normal(t.size)
    gr = _grams({"lag.a": a, "lag.b": bcol}, y)
    problem = SimpleNamespace(weights=np.ones(6), settings=SimpleNamespace(hac_lags=2))
    f = lsq.fit(gr, problem.weights, 2)
    effect = SimpleNamespace(name="lag", ranges=ranges)
    return f, held_at_bounds(problem, gr, list(gr.names), (effect,), f)


def test_an_amplitude_past_its_zero_bound_is_held_there_and_the_other_refitted():
    plain, (names, held) = _case(-0.05, {"a": (0.0, 1.5), "b": (0.0, 1.5)})
    assert plain.coefs()["lag.b"] < -0.03                     # least squares goes past the bound
    assert names == ["lag.a"]                                 # b held at 0: its column dropped
    a_alone = held.coefs()["lag.a"]
    assert abs(a_alone - (0.8 - 0.05 * 0.7)) < 0.02           # a takes b's share along a
    assert held.sse_block.sum() > plain.sse_block.sum()       # the bound costs a little fit


def test_amplitudes_inside_their_range_or_unsigned_are_left_alone():
    plain, (names, held) = _case(0.05, {"a": (0.0, 1.5), "b": (0.0, 1.5)})
    assert names == ["lag.a", "lag.b"] and held is plain
    plain, (names, held) = _case(-0.05, {"a": (-1.0, 1.5), "b": (-1.0, 1.5)})
    assert names == ["lag.a", "lag.b"] and held is plain
