"""What residual evidence is made of: the run residual, the evidence knobs, a line, the evidence record.

The shared vocabulary of every kind of evidence (``evidence_locked``, ``evidence_lines``,
``evidence_tones``, ``evidence_dependence``): :class:`RunResidual` (one run's residual and what
it may depend on), :class:`EvidenceSettings` (section ``evidence`` of ``pipelines/diagnose.yaml``),
:class:`Peak` (a narrowband line), :class:`Evidence` (everything :func:`evidence.analyse` finds,
with its JSON summary), and the one-clause sentences effects quote from it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS


@dataclass
class RunResidual:
    """One run's residual and what it may depend on (arrays over the run's ticks)."""

    run_id: str
    index: int
    heldout: bool
    flow: float
    freq: float
    dt_s: float
    time_s: np.ndarray
    fit: np.ndarray
    rest: np.ndarray
    theta_h: np.ndarray
    theta_k: np.ndarray
    omega_h: np.ndarray
    omega_k: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray

    @property
    def resid(self) -> np.ndarray:
        """Measured minus predicted (T, 6)."""
        return self.measured - self.predicted


@dataclass(frozen=True)
class EvidenceSettings:
    """Evidence knobs (``pipelines/diagnose.yaml`` section ``evidence``)."""

    #: highest frequency examined (Hz) by the stroke-locked, tone and Welch evidence (the ingest's low-pass cutoff)
    fmax_hz: float = 6.5
    #: highest frequency the narrowband line scan examines (Hz): past the low-pass cutoff, which lowers a line
    #: and the noise around it alike (an 8 Hz rig vibration through the 6 Hz, order-4 filter keeps its ratio)
    lines_fmax_hz: float = 9.0
    fmin_hz: float = 0.2
    welch_segment_s: float = 8.0
    #: narrowband peak: at least this ratio to the floor and significant at ``peak_alpha`` (Bonferroni over bins)
    peak_ratio: float = 3.0
    peak_alpha: float = 1e-3
    floor_window_hz: float = 1.2
    #: gait-locked power above ``locked_ratio`` times the noise expectation, significant at ``locked_alpha``
    locked_ratio: float = 3.0
    locked_alpha: float = 1e-3
    max_lag_s: float = 1.0
    #: runs used for the correlation evidence (an even spread over the campaign)
    correlation_runs: int = 48
    #: trend (drift) test level and smallest reported share of the residual
    trend_alpha: float = 1e-3
    trend_min_share: float = 0.05
    angle_bins: int = 8
    phase_bins: int = 16
    time_bins: int = 8


@dataclass
class Peak:
    """A narrowband residual peak not locked to the gait."""

    frequency_hz: float
    channels: list[str]
    ratio: dict[str, float]
    p: float
    #: found in the rest stretches before the runs (:func:`evidence_lines.rest_lines`), not in the motion
    at_rest: bool = False
    #: how far (Hz) another frequency may lie and still be this line (the scan's resolution)
    width_hz: float = 0.1
    #: the stronger line (Hz) this one is a stroke sideband of (f0 +- k gait frequency; see
    #: :func:`evidence_lines.mark_sidebands`), or None
    sideband_of: float | None = None
    #: where the rest stretches show it (:func:`evidence_lines.rest_where`): "" not at rest, "still" at
    #: rest in still water too (the rig's own), "flow" at rest only where water flows (carried by the
    #: flow), "rest" at rest with no still-water rest to tell the two apart
    rest_seen: str = ""


@dataclass
class Evidence:
    """Everything the residual shows, per channel (JSON-friendly through :meth:`summary`)."""

    mse: dict[str, float]
    locked_share: dict[str, float]
    locked_ratio: dict[str, float]
    locked_p: dict[str, float]
    freqs: np.ndarray
    psd_rest: np.ndarray                 # (F, 6) spectrum of the non-locked part
    floor: np.ndarray
    dof: float
    peaks: list[Peak]
    acf_lags_s: np.ndarray
    acf: np.ndarray                      # (L, 6)
    acf_bound: float
    ccf: dict[str, dict]                 # input -> {"lags_s", "r" (L, 6), "bound" (L, 6)}
    by_flow: dict[str, dict[str, float]]
    by_angle: dict
    by_phase: dict
    trend: dict[str, dict]
    zero_flow: dict
    rest: dict
    extra: dict = field(default_factory=dict)

    def summary(self) -> dict:
        """The evidence in a few numbers per channel, for diagnosis.json."""
        ch = list(WRENCH_CHANNELS)

        def r(x):
            return None if x is None or not np.isfinite(x) else float(f"{x:.4g}")

        return {
            "mse": {c: r(self.mse[c]) for c in ch},
            "gait_locked_share": {c: r(self.locked_share[c]) for c in ch},
            "gait_locked_power_ratio": {c: r(self.locked_ratio[c]) for c in ch},
            "narrowband_peaks": [{"frequency_hz": r(p.frequency_hz), "channels": p.channels,
                                  "peak_to_floor": {k: r(v) for k, v in p.ratio.items()},
                                  **({"at_rest": True} if p.at_rest else {}),
                                  **({"sideband_of_hz": r(p.sideband_of)} if p.sideband_of is not None else {}),
                                  **({"seen_at_rest": p.rest_seen} if p.rest_seen else {})}
                                 for p in self.peaks],
            "trend_per_s": {c: r(self.trend[c]["slope"]) for c in ch},
            "trend_t": {c: r(self.trend[c]["t"]) for c in ch},
            "mse_by_flow_speed": {k: {c: r(v[c]) for c in ch} for k, v in self.by_flow.items()},
            "zero_flow": self.zero_flow,
            "rest": self.rest,
            "max_abs_ccf_over_bound": {k: {c: r(v["max_ratio"][i]) for i, c in enumerate(ch)}
                                       for k, v in self.ccf.items()},
        }


# ------------------------------------------------------------------- clauses
def ccf_clause(ev: Evidence, key: str, what: str) -> str:
    """One clause: the residual's strongest cross-correlation with input ``key`` (empty when not computed)."""
    c = ev.ccf.get(key)
    if not c:
        return ""
    i = int(np.argmax(c["max_ratio"]))
    return f"the residual correlates with {what} ({WRENCH_CHANNELS[i]}: {c['max_ratio'][i]:.1f}x its Bartlett bound)"


def locked_clause(ev: Evidence) -> str:
    """One clause: the share of the worst channel's residual that repeats every stroke."""
    ch = list(WRENCH_CHANNELS)
    locked = max(ch, key=lambda k: ev.locked_share[k])
    return f"{ev.locked_share[locked]:.0%} of the {locked} residual repeats every stroke"
