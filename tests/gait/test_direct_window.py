"""A window net swum directly: the simulator runs it on each window's ticks (plus its memory) only, exactly."""

import numpy as np
import pytest
from models import small_lstm

from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.simulator import GaitBatch, simulate


class _Opaque(LegForceModel):
    """The same net behind an interface that hides its memory length: the simulator must use whole histories."""

    name = "opaque"

    def __init__(self, inner):
        self.inner = inner

    def wrench(self, motion):
        return self.inner.wrench(motion)

    def describe(self):
        return {"name": self.name}


@pytest.mark.slow
def test_window_net_on_window_ticks_gives_the_whole_history_numbers(robot):
    net = small_lstm(variant="lstm", residual_scale_n=0.05)
    rng = np.random.default_rng(3)
    gaits = GaitBatch.from_arrays(rng.uniform(-50, 10, 3), rng.uniform(-80, -20, 3), rng.uniform(0.2, 0.65, 3),
                                  rng.uniform(0, 2 * np.pi, (3, 4)))
    kw = dict(duration_s=12.0, window_s=3.0, max_window_s=6.0)
    sliced = simulate(gaits, net, robot, **kw)
    whole = simulate(gaits, _Opaque(net), robot, **kw)
    assert sliced.converged.all() and whole.converged.all()
    assert sliced.iterations == whole.iterations
    for name in ("x_m", "y_m", "yaw_rad", "leg_flow_mps"):
        np.testing.assert_allclose(getattr(sliced, name), getattr(whole, name), rtol=0, atol=1e-12, err_msg=name)
