"""The simulator's shortcuts give the numbers of the whole computation (issue 14.7, paper scale).

Within a fixed-point window only the gaits still iterating are predicted again (a frozen gait keeps
its wrenches), and a model with a fast path is asked for those legs over the window's ticks only.
Each test runs the whole computation beside the shortcut, with formulas and models written here.
"""

from dataclasses import replace

import numpy as np
import pytest
from models import LaggedEF, small_lstm

from workbench.gait.space import GaitSpace
from workbench.gait.tabulate import TabulatedLegModel, TabulationSettings, _filter_flow
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.simulator import DEFAULT_DT_S, simulate


class _Whole(LegForceModel):
    """A model behind an interface without fast path or memory length: every call is the whole history."""

    name = "whole"

    def __init__(self, inner):
        self.inner = inner

    def wrench(self, motion):
        return self.inner.wrench(motion)


def _gaits(n, seed):
    return GaitSpace().gaits(GaitSpace().sample(n, np.random.default_rng(seed)))


def test_filter_on_a_tick_range_equals_the_whole_filter():
    rng = np.random.default_rng(0)
    flow = rng.normal(0.1, 0.05, (5, 300))
    taps = rng.normal(size=9)
    whole = _filter_flow(flow, taps)
    # by hand: rest before t = 0 is the first tick repeated
    padded = np.concatenate([np.repeat(flow[:, :1], 8, axis=1), flow], axis=1)
    by_hand = sum(w * padded[:, 8 - lag:8 - lag + 300] for lag, w in enumerate(taps))
    np.testing.assert_allclose(whole, by_hand, rtol=0, atol=1e-14)
    for lo, hi in ((0, 300), (0, 5), (3, 40), (8, 9), (120, 300)):
        np.testing.assert_array_equal(_filter_flow(flow, taps, lo, hi), whole[:, lo:hi])


def test_ef_fast_path_on_some_legs_and_ticks_is_the_wrench():
    gaits = _gaits(3, 1)
    motion = gaits.leg_motion(np.arange(200) * DEFAULT_DT_S)
    flow = np.random.default_rng(2).uniform(-0.05, 0.3, motion.shape)
    ef = EmpiricalFormula()
    full = ef.wrench(replace(motion, flow_speed_mps=flow))
    provider = ef.flow_provider(motion)
    assert provider.partial
    legs = np.array([1, 4, 5, 11])
    np.testing.assert_array_equal(provider(flow, legs=legs, lo=17, hi=150), provider(flow)[legs, 17:150])
    np.testing.assert_allclose(provider(flow, legs=legs, lo=17, hi=150), full[legs, 17:150], rtol=1e-12, atol=1e-15)


def test_skipping_frozen_gaits_gives_the_whole_computation(robot):
    """A lagged EF (no fast path) agrees to the bit; the EF's fast path differs from its ``wrench`` by rounding only."""
    gaits = _gaits(5, 3)
    kw = dict(duration_s=12.0, window_s=4.0, max_window_s=8.0)
    for model in (EmpiricalFormula(), LaggedEF(0.03)):
        fast = simulate(gaits, model, robot, **kw)
        whole = simulate(gaits, _Whole(model), robot, **kw)
        assert fast.converged.all()
        assert fast.iterations == whole.iterations
        tol = 1e-12 if isinstance(model, EmpiricalFormula) else 0.0
        for name in ("x_m", "y_m", "yaw_rad", "leg_flow_mps"):
            np.testing.assert_allclose(getattr(fast, name), getattr(whole, name), rtol=0, atol=tol, err_msg=name)


@pytest.mark.slow
def test_tabulated_legs_and_ticks_on_request_equal_the_whole_call():
    """The tabulated LSTM asked for some legs over some ticks gives the whole call's numbers (float32 net: 1e-6)."""
    net = small_lstm(variant="lstm", residual_scale_n=0.1)
    gaits = _gaits(4, 4)
    n_ticks = 400
    motion = gaits.leg_motion(np.arange(n_ticks) * DEFAULT_DT_S)
    flow = 0.12 + 0.04 * np.sin(np.arange(n_ticks) * 0.05)[None, :] * np.linspace(0.5, 1.5, 16)[:, None]
    settings = TabulationSettings(mode="always")
    whole = TabulatedLegModel(net, gaits, settings, sim_dt_s=DEFAULT_DT_S).flow_provider(motion)(flow)
    tab = TabulatedLegModel(net, gaits, settings, sim_dt_s=DEFAULT_DT_S)
    provider = tab.flow_provider(motion)
    scale = np.abs(whole).max()
    for legs, lo, hi in ((np.array([2, 3, 9]), 0, 120), (np.array([0, 15]), 5, 20), (np.arange(16), 200, 400),
                         (np.array([7]), 30, 31)):
        got = provider(flow, legs=legs, lo=lo, hi=hi)
        assert got.shape == (legs.size, hi - lo, 6)
        np.testing.assert_allclose(got, whole[legs, lo:hi], rtol=0, atol=1e-6 * scale)
    # the start-up ticks come from the model itself, leg by leg
    direct = net.wrench(replace(motion, flow_speed_mps=flow))
    m = tab.source.memory_ticks
    np.testing.assert_allclose(whole[:, :m], direct[:, :m], rtol=0, atol=1e-5 * scale)


@pytest.mark.slow
def test_a_gaits_swim_does_not_depend_on_its_batch(robot):
    """Direct rollout of a window net: each gait alone and in a batch (where others freeze earlier) agree."""
    net = small_lstm(variant="ef_residual", residual_scale_n=0.05)
    gaits = _gaits(2, 5)
    kw = dict(duration_s=3.0, window_s=1.0, max_window_s=2.0)
    batch = simulate(gaits, net, robot, **kw)
    assert batch.converged.all()
    for i in range(len(gaits)):
        alone = simulate(gaits.rows([i]), net, robot, **kw)
        for name in ("x_m", "y_m", "yaw_rad"):
            np.testing.assert_allclose(getattr(alone, name)[0], getattr(batch, name)[i], rtol=0, atol=1e-7,
                                       err_msg=f"gait {i} {name}")
