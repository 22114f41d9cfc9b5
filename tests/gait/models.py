"""Leg force models with memory for the gait tests: a lagged EF and a small FED-LSTM-style net."""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.motion import LegMotion


class LaggedEF(LegForceModel):
    """The EF wrench through a first-order lag (time constant ``tau_s``): a model with unbounded memory.

    Like the circulatory lag of a real web, the force trails the motion; the filter starts at rest
    on the first tick's EF value, so a rollout has a start-up transient, as a recurrent model would.
    """

    name = "lagged-ef"

    def __init__(self, tau_s: float = 0.08):
        self.tau_s = tau_s
        self.ef = EmpiricalFormula()

    def wrench(self, motion: LegMotion) -> np.ndarray:
        w = self.ef.wrench(motion)
        a = np.exp(-motion.dt_s / self.tau_s)
        zi = (a * w[:, :1, :])  # steady start: y[-1] = x[0]
        y, _ = lfilter([1 - a], [1, -a], w, axis=1, zi=zi)
        return y


def small_lstm(seed: int = 0, hidden: int = 16, residual_scale_n: float = 0.03, variant: str = "ef_residual"):
    """A FED-LSTM with random weights on the real LearnedLegModel code path.

    ``ef_residual``: the EF plus an LSTM memory term of about ``residual_scale_n``; ``lstm``: the
    bare net (outputs of that size, no physics).
    """
    import torch

    from workbench.learn.config import ModelSettings
    from workbench.learn.legmodel import LearnedLegModel
    from workbench.learn.nets import build_net
    from workbench.learn.windows import Normalisation

    torch.manual_seed(seed)
    cfg = ModelSettings(variant=variant, hidden_size=hidden, num_layers=2, dropout=0.0, backbone="lstm")
    net = build_net(cfg, 16)
    s = residual_scale_n
    norm = Normalisation((0.1, -45.0, 0.0, 0.0, 0.0), (0.1, 30.0, 50.0, 100.0, 200.0), (0.0,) * 6,
                         (s, s, s, s * 0.1, s * 0.1, s * 0.1))
    return LearnedLegModel(net, model=cfg, seq_len=16, dt_s=1 / 65, norm=norm, name="lstm")
