"""first_order_lag (blocked recurrence) against the tick-by-tick loop it replaces, and the exact response."""

import numpy as np
import pytest

from workbench.diagnose.flowterms import first_order_lag

DT = 1 / 65


def _reference(u, rate_per_s, dt_s):
    """The former implementation: one first-order-hold step per tick, in a Python loop."""
    u = np.asarray(u, float)
    rate = np.asarray(rate_per_s, float)
    rate = np.broadcast_to(rate, u.shape[:max(2, rate.ndim)])
    r = 0.5 * (rate[:, 1:] + rate[:, :-1]) * dt_s
    e = np.exp(-r)
    g = np.where(r > 1e-9, -np.expm1(-r) / np.maximum(r, 1e-300), 1.0 - r / 2)
    shape = r.shape + (1,) * (u.ndim - r.ndim)
    e, g = e.reshape(shape), g.reshape(shape)
    out = np.empty_like(u)
    out[:, 0] = u[:, 0]
    for k in range(1, u.shape[1]):
        u0, u1 = u[:, k - 1], u[:, k]
        out[:, k] = u1 + e[:, k - 1] * (out[:, k - 1] - u0) - g[:, k - 1] * (u1 - u0)
    return out


def _rates(rng, shape, kind):
    """Rates (1/s) whose steps r = rate * dt span 1e-12 .. 80."""
    if kind == "constant":  # one rate per series (and lag), held over time
        one = 10 ** rng.uniform(-12, np.log10(80), (shape[0], 1) + shape[2:])
        return np.broadcast_to(one, shape) / DT
    if kind == "varying":  # a new rate every tick, anywhere in the range
        return 10 ** rng.uniform(-12, np.log10(80), shape) / DT
    # slowly varying around a level per series, from vanishing to stiff
    t = np.arange(shape[1]).reshape((1, -1) + (1,) * (len(shape) - 2))
    level = rng.uniform(-12, np.log10(80), (shape[0], 1) + shape[2:])
    return 10 ** np.clip(level + 0.5 * np.sin(2 * np.pi * t / 700 + rng.uniform(0, 6, level.shape)), -12, np.log10(80)) / DT


CASES = [  # (u shape, rate shape)
    ((3, "T"), (3, "T")),
    ((2, "T", 4), (2, "T")),              # one rate for several inputs
    ((2, "T", 3, 2), (2, "T")),           # (B, T, 3, 2) input
    ((2, "T", 2, 2), (2, "T", 2)),        # two lags of a (force, couple) pair, as the Wagner law
    ((2, "T", 3), (2, "T", 3)),           # a rate per input
    ((1, "T", 2, 2, 2), (1, "T", 2)),
]


@pytest.mark.parametrize("kind", ["constant", "varying", "smooth"])
@pytest.mark.parametrize("ushape, rshape", CASES)
@pytest.mark.parametrize("n_ticks", [1, 2, 40, 64, 65, 97, 1000, 2113, 5000])
def test_matches_the_tick_by_tick_loop(n_ticks, ushape, rshape, kind):
    rng = np.random.default_rng([n_ticks, len(ushape), len(rshape), len(kind)])
    ushape = tuple(n_ticks if s == "T" else s for s in ushape)
    rshape = tuple(n_ticks if s == "T" else s for s in rshape)
    # a wandering signal with jumps, on an offset
    u = 3.0 + np.cumsum(rng.standard_normal(ushape), axis=1) * 0.2 + 5 * (rng.random(ushape) < 0.01)
    rate = _rates(rng, rshape, kind)
    got = first_order_lag(u, rate, DT)
    ref = _reference(u, rate, DT)
    assert got.shape == u.shape
    assert np.all(np.isfinite(got))
    scale = np.abs(u).max()
    assert np.abs(got - ref).max() <= 1e-9 * scale


def test_scalar_and_broadcast_rates():
    rng = np.random.default_rng(3)
    u = np.cumsum(rng.standard_normal((4, 777, 2)), axis=1)
    for rate in (7.0, np.full((4, 1), 2.5), rng.uniform(0.1, 100, (1, 777))):
        assert np.abs(first_order_lag(u, rate, DT) - _reference(u, rate, DT)).max() <= 1e-9 * np.abs(u).max()


def test_extreme_steps_stay_finite_and_exact():
    # r from 0 (the output holds its start) to far beyond where exp of a cumulative sum overflows
    # (the output is the input)
    u = np.cumsum(np.random.default_rng(4).standard_normal((3, 3000)), axis=1)
    scale = np.abs(u).max()
    for r in (0.0, 1e-300, 1e-12, 80.0, 800.0, 1e6):
        rate = np.full(u.shape, r / DT)
        got = first_order_lag(u, rate, DT)
        assert np.all(np.isfinite(got))
        assert np.abs(got - _reference(u, rate, DT)).max() <= 1e-9 * scale
    assert np.abs(first_order_lag(u, 0.0, DT) - u[:, :1]).max() <= 1e-12 * scale
    assert np.abs(first_order_lag(u, 1e9 / DT, DT) - u).max() <= 1e-8 * scale


@pytest.mark.parametrize("n_ticks", [50, 4000])
def test_step_follows_the_exponential(n_ticks):
    rates = np.array([0.05, 1.0, 10.0, 65.0, 500.0])        # 1/s, several lags at once
    t = np.arange(n_ticks) * DT
    u = np.ones((1, n_ticks, len(rates)))
    u[:, 0] = 0.0                                             # the step, as a ramp over the first tick
    got = first_order_lag(u, np.broadcast_to(rates, u.shape), DT)[0]
    # exact response to that input: x(dt) = 1 - (1 - e) / r, then 1 - x decays as exp(-rate t)
    r = rates * DT
    exact = 1.0 - np.expm1(r) / r * np.exp(-rates * t[:, None])
    exact[0] = 0.0
    assert np.abs(got - exact).max() < 1e-12
    # which is the step response 1 - exp(-rate t) delayed by half a tick, to second order in r
    slow = rates * DT < 0.1
    assert np.abs(got - (1 - np.exp(-rates * (t[:, None] - DT / 2))))[1:, slow].max() < 1e-4
