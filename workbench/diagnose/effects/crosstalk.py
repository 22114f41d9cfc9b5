"""Load-cell crosstalk: one channel reads a share of another (``loadcell_crosstalk``; docs/diagnose.md)."""

from __future__ import annotations

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose.effects.base import Context, Effect, Terms
from workbench.diagnose.evidence import ccf_clause

SHORT = tuple(c.split("_")[0] for c in WRENCH_CHANNELS)  # fx, fy, fz, tx, ty, tz


class LoadcellCrosstalk(Effect):
    """Reading = (I + X) @ true wrench, X off-diagonal; entries x_<to>_<from>.

    Sources the model never excites are left out, and of two (nearly) proportional sources
    only the larger is fitted (its entry then stands for both; see ``aliases``).
    """

    name = "loadcell_crosstalk"
    ranges = {"x_*": (-0.15, 0.15)}
    stage = "sensor"
    physical = False
    prunable = True
    reads_prediction = True
    formula = "W_read = (I + X) W, X off-diagonal"

    def __init__(self, pairs: list[tuple[int, int]] | None = None, aliases: dict[str, str] | None = None):
        self.pairs = pairs if pairs is not None else [(i, j) for i in range(6) for j in range(6) if i != j]
        self.aliases = dict(aliases or {})

    def options(self) -> dict:  # noqa: D102
        return {"pairs": [list(p) for p in self.pairs], "aliases": dict(self.aliases)}

    @classmethod
    def from_options(cls, options: dict | None = None) -> "LoadcellCrosstalk":  # noqa: D102
        opts = dict(options or {})
        if "pairs" in opts:
            opts["pairs"] = [tuple(p) for p in opts["pairs"]]
        return cls(**opts)

    def configure(self, sample) -> "LoadcellCrosstalk":
        """Only the entries this campaign can identify (:meth:`configured` on the base model's prediction)."""
        prediction, mask = sample()
        return self.configured(prediction, mask)

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        return ccf_clause(ev, "model_force", "the model's force in another channel")

    def notes(self, coefs: dict[str, float]) -> list[str]:  # noqa: D102
        return [f"{k} stands for {k}{self.aliases[k]} (proportional sources in this model)"
                for k in coefs if k in self.aliases]

    @staticmethod
    def entry(to: int, frm: int) -> str:
        """Parameter name of one entry."""
        return f"x_{SHORT[to]}_{SHORT[frm]}"

    def linear_names(self):  # noqa: D102
        return [self.entry(i, j) for i, j in self.pairs]

    def configured(self, prediction: np.ndarray, mask: np.ndarray, collinear: float = 0.995) -> "LoadcellCrosstalk":
        """A copy fitting only identifiable entries, judged on a sample of the predicted true wrench."""
        p = prediction[mask]  # (n, 6)
        rms = np.sqrt(np.mean(p * p, axis=0))
        scale = rms.max() if rms.max() > 0 else 1.0
        live = [j for j in range(6) if rms[j] > 1e-6 * scale]
        keep, aliases = [], {}
        for j in sorted(live, key=lambda j: -rms[j]):
            dup = None
            for k in keep:
                c = np.corrcoef(p[:, j], p[:, k])[0, 1] if rms[j] > 0 and rms[k] > 0 else 0.0
                if abs(c) >= collinear:
                    dup = k
                    break
            if dup is None:
                keep.append(j)
            else:
                ratio = float(np.dot(p[:, j], p[:, dup]) / np.dot(p[:, dup], p[:, dup]))
                for i in range(6):
                    if i not in (j, dup):
                        aliases[self.entry(i, dup)] = (aliases.get(self.entry(i, dup), "")
                                                       + f" + {ratio:.4g} {self.entry(i, j)}")
        pairs = [(i, j) for j in sorted(keep) for i in range(6) if i != j]
        return type(self)(pairs, aliases)

    def sensor_terms(self, ctx: Context, nl: dict, prediction: np.ndarray) -> Terms:  # noqa: D102
        names, cols, sup = [], [], []
        for i, j in self.pairs:
            col = np.zeros_like(prediction)
            col[..., i] = prediction[..., j]
            s = np.zeros(6, bool)
            s[i] = True
            names.append(self.entry(i, j))
            cols.append(col)
            sup.append(s)
        return Terms(names, cols, sup)


LIBRARY_RANK = 5  # place in the library's order (workbench.diagnose.library._in_tree)

EFFECTS = (LoadcellCrosstalk,)
