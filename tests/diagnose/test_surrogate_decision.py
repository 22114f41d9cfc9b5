"""`fit.surrogate_search: auto` decides by what the model is, not by how busy the machine is.

Measured 30 Nov 2026: the FED-LSTM cost 37-60 us a tick against the 40 us limit, so the timed rule flipped
between cases of one battery run, and with it the searches (598 s for one case) and the selection path.
"""

from __future__ import annotations

import numpy as np

from workbench.diagnose.problem import expensive, us_per_tick
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.motion import LegMotion


class WindowNet(LegForceModel):
    """A stand-in plugin model shaped like the FED-LSTM: a window of ``seq_len`` steps per predicted tick."""

    name = "window"
    seq_len = 32

    def wrench(self, motion):
        return np.zeros((*motion.theta_h_deg.shape, 6))


class Declared(WindowNet):
    """A plugin model that says what it costs (its word wins over its shape)."""

    expensive = False


class Wrapper(LegForceModel):
    """A model around another one (as an augmented model is around its base)."""

    def __init__(self, base):
        self.base = base

    def wrench(self, motion):
        return self.base.wrench(motion)


def _motion(b=2, t=200):
    z = np.zeros((b, t))
    return LegMotion(0.01, z + 10.0, z - 40.0, z, z, z + 0.1, z, z)


def test_a_window_net_uses_the_surrogate_whatever_its_timing():
    for us in (1.0, 39.0, 41.0, 500.0):
        on, why = expensive(WindowNet(), lambda us=us: us, 40.0)
        assert on and "window net, 32 steps" in why
    assert expensive(Wrapper(WindowNet()), lambda: 1.0, 40.0)[0]
    assert expensive(Wrapper(Wrapper(WindowNet())), lambda: 1.0, 40.0)[0]


def test_a_declared_cost_wins_and_only_an_undeclared_model_is_timed():
    assert expensive(Declared(), lambda: 500.0, 40.0) == (False, "Declared.expensive is False")
    ef = EmpiricalFormula()
    assert expensive(ef, lambda: 3.0, 40.0)[0] is False
    on, why = expensive(ef, lambda: 45.0, 40.0)
    assert on and why.startswith("timed: 45 us")
    assert expensive(Wrapper(ef), lambda: 3.0, 40.0)[0] is False


def test_the_timing_is_the_fastest_of_three_runs():
    calls = []

    class Slow(Wrapper):
        def wrench(self, motion):
            calls.append(1)
            return super().wrench(motion)

    us = us_per_tick(Slow(EmpiricalFormula()), _motion())
    assert len(calls) == 3 and us > 0


def test_batches_shrink_for_a_window_net_by_the_same_rule():
    from workbench.diagnose.data import DataSettings
    from workbench.diagnose.loop_threads import _chunks_for

    data = DataSettings()
    assert data.chunk_runs > 12
    # the stand-in window net answers in microseconds: timed, it would keep the large batches
    assert _chunks_for(WindowNet(), data).chunk_runs == 12
    assert _chunks_for(Declared(), data).chunk_runs == data.chunk_runs
    assert _chunks_for(EmpiricalFormula(), data).chunk_runs == data.chunk_runs
