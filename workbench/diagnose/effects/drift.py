"""Load-cell drift: a reading that creeps linearly in time within each run (``sensor_drift``; docs/diagnose.md).

A drift is linear in the time since the run's first trigger edge and common to every run. A
base model's own misfit also changes through a run, but it is locked to the run's ends: the
controller eases the leg in and out, and a model that remembers only a short window cannot
carry the slow settling of the flow from rest (the FED-LSTM's fz residual on the rich virtual
tunnel deviates from its steady stroke-locked waveform by 20-60 mN in the first 1-3 s and the
last 0.5 s of a run, against about 2 mN in between, and its per-run slopes scatter by 1.3 mN/s
with no drift at all). Its level also differs from run to run by tens of mN, which a drift's
column ``t`` (mean 4-7 s, depending on the run's length) would read as drift.

So the drift is *fitted* on each run's settled span only, and within runs only: its column is
``t`` minus its mean over the run's settled span, and zero on the unsettled ends. That is the
drift's column with a per-run nuisance (the run's level, a free line on each unsettled end)
projected out, so its least-squares rate is that of a joint fit with the nuisance on every run
(Frisch-Waugh-Lovell) while the other effects' fits keep every run's level. The model *predicts*
with ``rate * t`` (``Terms.predict``), the formula, and the fits take the rest of it (each run's
level, its ends) off the readings at the current rate (``Terms.fit_offset``), so that no other
effect takes a drift's level for its own (a weight fitted 11 mN of a 2 mN/s drift's level
before). The held-out *test* needs the nuisance itself: a 2 s block's share of the column times
the run's level (tens of mN) swamps the drift's gain in that block although it cancels over the
run. So the selection judges the drift under ``judge`` (:meth:`SensorDrift.judged_as`): the
nuisance as per-run columns in each fitted channel (the run's level, a free line on each
unsettled end and the run's stroke-locked waveform, ``stroke`` gait harmonics), fitted on every
run, held-out runs too, and the same nuisance without the drift (:meth:`SensorDrift.null_variants`)
as the null its gain is measured against. The test's noise is then what is left of the base
model's misfit beyond each run's level, ends and stroke-locked waveform: its own slow trends
within the settled span stay in it (and in the estimate: about -0.06 mN m/s in tx, -0.05 mN/s in
fz for the FED-LSTM on the rich tunnel).

Which ends are unsettled is read from each run's own residual (measured minus the prediction the
drift is first tried beside), not from a constant: the residual's steady waveform (mean, line and
gait harmonics) is fitted on the middle half of the run's analysed span, and an end is unsettled
as far in as a ``window_s`` (0.5 s) window deviates from it by more than ``settle_ratio`` (5)
times the middle windows' median deviation (RMS per window and channel, worst channel); each end
stays within its outer quarter. Option ``settling: false`` fits the plain column ``t``.
"""

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

    def __init__(self, settling: bool = True, settle_ratio: float = 5.0, window_s: float = 0.5, stroke: int = 12,
                 flow_degree: int = 1):
        self.settling = bool(settling)
        self.flow_degree = int(flow_degree)
        self.stroke = int(stroke)
        self.settle_ratio = float(settle_ratio)
        self.window_s = float(window_s)
        # per batch of runs (by identity; the batch is kept so that its id is not reused): the
        # settled span of each run, chosen once from the residual the drift is first tried beside
        self._spans: dict[int, tuple[object, np.ndarray]] = {}

    def __repr__(self) -> str:
        return f"SensorDrift(settling={self.settling})"

    def options(self) -> dict:  # noqa: D102
        return {"settling": self.settling, "settle_ratio": self.settle_ratio, "window_s": self.window_s,
                "stroke": self.stroke, "flow_degree": self.flow_degree}

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        c = max(WRENCH_CHANNELS, key=lambda k: abs(ev.trend[k]["t"]))
        return f"the residual trends with time in the run ({c}: {ev.trend[c]['slope']:.3g}/s, t = {ev.trend[c]['t']:.1f})"

    @staticmethod
    def entry(c: int) -> str:
        """Parameter name for channel ``c``."""
        return f"rate_{WRENCH_CHANNELS[c]}_per_s"

    def linear_names(self):  # noqa: D102
        return [self.entry(c) for c in range(6)]

    def judged_as(self, nl: dict) -> dict | None:  # noqa: D102
        return {**nl, "judge": 1.0} if self.settling else None

    def null_variants(self, nl: dict) -> list[dict]:  # noqa: D102
        # the nuisance alone: what each run's level and unsettled ends gain without a drift
        return [{**nl, "null": 1.0}] if nl.get("judge") else []

    def reading_inverse(self, nl: dict, coefs: dict, dt_s: float):
        """An added drift: the prediction carries ``rate t`` already, so the residual is the corrected one."""
        return lambda x: x

    def sensor_terms(self, ctx: Context, nl: dict, prediction: np.ndarray) -> Terms:  # noqa: D102
        t = np.maximum(ctx.time_s, 0.0)
        spans = self._settled(ctx.rs, prediction) if self.settling else None
        fit_t = t
        if spans is not None:
            rs = ctx.rs
            settled = rs.fit & (rs.time_s >= spans[:, :1]) & (rs.time_s <= spans[:, 1:])
            n = np.maximum(settled.sum(axis=1, keepdims=True), 1)
            mean = (t * settled).sum(axis=1, keepdims=True) / n
            fit_t = np.where(settled, t - mean, 0.0)
        within = np.zeros_like(t) if nl.get("null") else fit_t
        if spans is not None and not nl.get("null"):
            within = within * flow_trend_free(ctx.rs, within, self.flow_degree)
        offset = None
        names, cols, sup, pred = [], [], [], {}
        for c in range(6):
            col = np.zeros(t.shape + (6,))
            col[..., c] = within
            rate = float(getattr(ctx, "coefs", {}).get(f"{self.name}.{self.entry(c)}", 0.0))
            if spans is not None and rate:
                # the part the within-run column leaves out (each run's level and its ends) at the current rate
                offset = np.zeros(t.shape + (6,)) if offset is None else offset
                offset[..., c] = rate * (t - fit_t)
            s = np.zeros(6, bool)
            s[c] = True
            names.append(self.entry(c))
            cols.append(col)
            sup.append(s)
            if spans is not None:
                p = np.zeros(t.shape + (6,))
                p[..., c] = t
                pred[self.entry(c)] = p
        terms = Terms(names, cols, sup, predict=pred or None, fit_offset=offset)
        if spans is not None and nl.get("judge"):
            self._nuisance(terms, ctx.rs, t, spans)
        return terms

    def _nuisance(self, terms: Terms, rs, t: np.ndarray, spans: np.ndarray) -> None:
        """Per-run columns in every channel (in place): level, ends and stroke-locked waveform.

        The run's level, a free line on each unsettled end and, with ``stroke`` gait harmonics,
        the run's own stroke-locked waveform (the base model's misfit that repeats every stroke).
        """
        moving = rs.fit
        start = moving & (rs.time_s < spans[:, :1])
        end = moving & (rs.time_s > spans[:, 1:])
        parts = {"level": moving, "start": start, "start_t": start * t, "end": end, "end_t": end * t}
        freq = np.where(np.isfinite(rs.freq) & (rs.freq > 0), rs.freq, 0.0)[:, None]
        for j in range(1, self.stroke + 1):
            w = 2 * np.pi * j * freq * rs.time_s
            parts[f"sin{j}"] = moving * np.sin(w)
            parts[f"cos{j}"] = moving * np.cos(w)
        for c in range(6):
            for k, v in parts.items():
                col = np.zeros(t.shape + (6,))
                col[..., c] = v
                terms.local_names.append(f"{k}_{WRENCH_CHANNELS[c]}")
                terms.local.append(col)
                terms.local_owner.append(self.entry(c))

    # ------------------------------------------------------------------ the settled span
    def _settled(self, rs, prediction: np.ndarray) -> np.ndarray | None:
        """(B, 2) start and end of each run's settled span (None: not a measured batch)."""
        if not all(hasattr(rs, k) for k in ("y", "fit", "freq")):
            return None  # a model's prediction for new motion: no readings, the plain column
        key = id(rs)
        if key not in self._spans:
            spans = np.array([settled_span(rs.time_s[i], rs.y[i] - prediction[i], rs.fit[i], float(rs.freq[i]),
                                           self.settle_ratio, self.window_s) for i in range(rs.time_s.shape[0])])
            self._spans[key] = (rs, spans)
        return self._spans[key][1]


def flow_trend_free(rs, within: np.ndarray, degree: int) -> np.ndarray:
    """(B, 1) per-run factors that make a training batch's drift column free of a trend growing with flow speed.

    A load cell's drift is the same in every run; a base model's own slow misfit within the
    settled span is not: it follows the flow (the flow's slow settling, which a model that
    remembers a short window cannot carry). Measured with the FED-LSTM on the battery's rich
    tunnel, a 0.3 mN m/s tx drift fitted on each flow speed alone read 0.277 (still water), 0.216
    (0.12 m/s) and 0.176 (0.25 m/s): the base's own tx trend, about -0.4 mN m/s per m/s. So the
    drift is *estimated* beside a nuisance trend ``t U^d`` (d = 1..``degree``, shared by the
    batch's runs): by Frisch-Waugh-Lovell its column is run r's column times ``g_r = 1 - sum_d
    a_d U_r^d``, the weighted least-squares residual of 1 on the flow powers over the batch's
    runs (weights: each run's column energy). The rate then comes from what is common to every
    flow speed, in still water where there is some. The model still predicts ``rate t``.
    Held-out batches, and a batch with fewer distinct flow speeds than ``degree + 1`` (the trend
    could not be told from the drift), keep factor 1.
    """
    ones = np.ones((within.shape[0], 1))
    flow = np.asarray(getattr(rs, "flow", np.full(within.shape[0], np.nan)), float)
    if degree <= 0 or getattr(rs, "heldout", True) or not np.all(np.isfinite(flow)):
        return ones
    weight = np.sum(within * within, axis=1)
    used = weight > 0
    levels = np.unique(np.round(flow[used], 4))
    degree = min(degree, len(levels) - 1)
    if degree <= 0:
        return ones
    powers = np.stack([flow ** d for d in range(1, degree + 1)], axis=1)  # (B, degree)
    sw = np.sqrt(weight)
    coef, *_ = np.linalg.lstsq(powers * sw[:, None], sw, rcond=None)
    g = 1.0 - powers @ coef
    return g[:, None]


def settled_span(t: np.ndarray, resid: np.ndarray, fit: np.ndarray, freq: float, ratio: float = 5.0,
                 window_s: float = 0.5, cutoff_hz: float = 6.0, max_harmonics: int = 12) -> tuple[float, float]:
    """Where one run's residual has settled: ``(start, end)`` in the time since its first trigger edge.

    The steady waveform (mean, line, gait harmonics below ``cutoff_hz``) is fitted on the middle
    half of the analysed ticks ``fit``; windows of ``window_s`` whose RMS deviation from it exceeds
    ``ratio`` times the middle windows' median (per channel, worst channel) mark the unsettled
    ends, each within its outer quarter. The whole span when the run is too short to tell.
    """
    m = np.asarray(fit, bool)
    if m.sum() < 16:
        return (-np.inf, np.inf)
    tt, rr = t[m], resid[m]
    t0, t1 = float(tt[0]), float(tt[-1])
    quarter = 0.25 * (t1 - t0)
    mid = (tt >= t0 + quarter) & (tt <= t1 - quarter)
    cols = [np.ones_like(tt), tt - tt.mean()]
    if np.isfinite(freq) and freq > 0:
        k = min(max(1, int(np.floor(cutoff_hz / freq))), max_harmonics, max(1, (int(mid.sum()) - 4) // 4))
        w = 2 * np.pi * freq * tt
        for j in range(1, k + 1):
            cols += [np.sin(j * w), np.cos(j * w)]
    x = np.column_stack(cols)
    if mid.sum() <= x.shape[1] + 2:
        return (-np.inf, np.inf)
    coef, *_ = np.linalg.lstsq(x[mid], rr[mid], rcond=None)
    dev = rr - x @ coef
    win = np.floor((tt - t0) / window_s).astype(int)
    nw = int(win.max()) + 1
    rms = np.zeros((nw, resid.shape[-1]))
    inner = np.zeros(nw, bool)
    for i in range(nw):
        sel = win == i
        if sel.any():
            rms[i] = np.sqrt((dev[sel] ** 2).mean(axis=0))
            inner[i] = bool(mid[sel].all())
    if not inner.any():
        return (-np.inf, np.inf)
    level = np.median(rms[inner], axis=0)
    score = (rms / np.maximum(level, 1e-12 * max(float(level.max()), 1e-300))).max(axis=1)
    lo = t0 + window_s * np.arange(nw)
    hi = np.minimum(lo + window_s, t1)
    bad = score > ratio
    first = bad & (hi <= t0 + quarter + window_s)
    last = bad & (lo >= t1 - quarter - window_s)
    start = min(float(hi[first].max()), t0 + quarter) if first.any() else -np.inf
    end = max(float(lo[last].min()), t1 - quarter) if last.any() else np.inf
    return (start, end)


LIBRARY_RANK = 6  # place in the library's order (workbench.diagnose.library._in_tree)

EFFECTS = (SensorDrift,)
