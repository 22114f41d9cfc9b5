"""Fixture builders of the plan tests: analytic ensembles whose disagreement is planted by formula.

A plain module (not a conftest): a test file imports it by its unique name, which a bare
``from conftest import ...`` is not when several folders' conftests are loaded.
"""

from __future__ import annotations

import numpy as np


class PlantedMember:
    """A leg force model: a shared wrench plus a member-specific bump where the flow speed exceeds ``u0``.

    The bump is ``amp * (flow - u0)_+ / 0.1`` on every channel, so the members agree below ``u0``
    and disagree above it: the ensemble's uncertainty lives at high flow by construction.
    """

    def __init__(self, amp: float, u0: float = 0.15, seq_len: int = 4, dt_s: float = 1 / 65):
        from workbench.learn.windows import Normalisation

        self.amp, self.u0, self.seq_len, self.dt_s = amp, u0, seq_len, dt_s
        self.norm = Normalisation((0.15, -40.0, 30.0, 0.0, 0.0), (0.1, 30.0, 30.0, 100.0, 100.0),
                                  (0.0,) * 6, (1.0,) * 6)
        self.name = "planted"

    def wrench(self, motion) -> np.ndarray:
        base = 0.1 * np.sin(np.deg2rad(motion.theta_h_deg))[..., None] * np.ones(6)
        bump = self.amp * np.clip(motion.flow_speed_mps - self.u0, 0, None)[..., None] / 0.1
        return base + bump * np.ones(6)


def planted_ensemble(amps=(-1.0, -0.3, 0.4, 1.0), u0: float = 0.15):
    """An Ensemble of PlantedMembers with unit noise and scale."""
    from workbench.learn.ensemble import Ensemble

    return Ensemble([PlantedMember(a, u0) for a in amps], np.full(6, 0.01), np.ones(6), {})
