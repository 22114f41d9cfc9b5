"""Load-cell drift: a reading that creeps linearly in time within each run (``sensor_drift``; docs/diagnose.md)."""

from __future__ import annotations

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose.effects.base import Context, Effect, Terms


class SensorDrift(Effect):
    """Reading drifts linearly with the time since the run's first trigger edge: rate_<channel>_per_s."""

    name = "sensor_drift"
    stage = "sensor"
    physical = False
    prunable = True
    formula = "W_read += rate * t, t since the first trigger edge"

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        c = max(WRENCH_CHANNELS, key=lambda k: abs(ev.trend[k]["t"]))
        return f"the residual trends with time in the run ({c}: {ev.trend[c]['slope']:.3g}/s, t = {ev.trend[c]['t']:.1f})"

    @staticmethod
    def entry(c: int) -> str:
        """Parameter name for channel ``c``."""
        return f"rate_{WRENCH_CHANNELS[c]}_per_s"

    def linear_names(self):  # noqa: D102
        return [self.entry(c) for c in range(6)]

    def sensor_terms(self, ctx: Context, nl: dict, prediction: np.ndarray) -> Terms:  # noqa: D102
        t = np.maximum(ctx.time_s, 0.0)
        names, cols, sup = [], [], []
        for c in range(6):
            col = np.zeros(t.shape + (6,))
            col[..., c] = t
            s = np.zeros(6, bool)
            s[c] = True
            names.append(self.entry(c))
            cols.append(col)
            sup.append(s)
        return Terms(names, cols, sup)


LIBRARY_RANK = 6  # place in the library's order (workbench.diagnose.library._in_tree)

EFFECTS = (SensorDrift,)
