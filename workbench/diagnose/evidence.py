"""Residual evidence, as a fluid dynamicist reads it (Ljung-style residual analysis, per channel).

* **Gait-locked vs the rest.** Each run's residual is split by harmonic regression on the gait
  frequency (harmonics up to the low-pass cutoff) into the part that repeats every stroke and
  the rest. A model error of the fluid physics repeats every stroke; noise, drift, a pump tone
  or electrical pickup do not.
* **Spectrum.** Welch spectrum of the rest, averaged over runs; narrowband peaks (locked to
  nothing the rig does, since every run has its own gait frequency) are found by their ratio
  to a running-median floor, with a chi-square test at the spectrum's degrees of freedom.
* **Gait-locked power test.** Power in the gait harmonics against what noise of the measured
  floor would put there.
* **Whiteness and cross-correlation.** Autocorrelation with white-noise bounds, and
  cross-correlation with the inputs, the model's force and its derivatives over lags, with
  Bartlett's bounds (valid for two coloured but independent signals).
* **Dependence.** Residual MSE against flow speed, joint angle, stroke phase and time in the
  run (a drift has a slope), and behaviour at zero flow and at rest.

The kinds of evidence live in their own modules (``evidence_base``: the records and settings;
``evidence_locked``: gait-locked part and power test; ``evidence_lines``: spectrum and lines;
``evidence_tones``: flow tones; ``evidence_dependence``: correlations, bins and drift);
:func:`analyse` here puts them together. Every name they define is re-exported from here.
"""

from __future__ import annotations

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose.evidence_base import (
    Evidence,
    EvidenceSettings,
    Peak,
    RunResidual,
    ccf_clause,
    locked_clause,
)
from workbench.diagnose.evidence_dependence import _binned, correlations, trend_test
from workbench.diagnose.evidence_lines import (
    _near_harmonic,
    _scan_grid,
    _segment,
    find_peaks,
    line_scan,
    mark_sidebands,
    peaks,
    rest_lines,
    rest_spectrum,
    rest_where,
    spectral_floor,
)
from workbench.diagnose.evidence_locked import (
    MAX_HARMONICS,
    _clock_jitter,
    _harmonic_amp2,
    _harmonic_fit,
    gait_locked,
    harmonic_tolerance,
    locked_test,
)
from workbench.diagnose.evidence_tones import flow_tone_peaks, tone_scan

__all__ = [
    "RunResidual",
    "EvidenceSettings",
    "Peak",
    "Evidence",
    "ccf_clause",
    "locked_clause",
    "MAX_HARMONICS",
    "_harmonic_fit",
    "gait_locked",
    "harmonic_tolerance",
    "_segment",
    "rest_spectrum",
    "spectral_floor",
    "find_peaks",
    "_harmonic_amp2",
    "_clock_jitter",
    "locked_test",
    "correlations",
    "_binned",
    "trend_test",
    "_near_harmonic",
    "_scan_grid",
    "line_scan",
    "peaks",
    "rest_lines",
    "rest_where",
    "mark_sidebands",
    "analyse",
    "tone_scan",
    "flow_tone_peaks",
]


def analyse(runs: list[RunResidual], settings: EvidenceSettings | None = None, cutoff_hz: float = 6.0,
            model_force: list[np.ndarray] | None = None, lowpass=None) -> Evidence:
    """Evidence from run residuals (analysis ticks; lines also from the rest stretches before the runs).

    ``lowpass``: the ingest's zero-phase low-pass (``chain.Lowpass``), which the rest-stretch
    line scan divides out of its floor (:func:`rest_lines`; None: the readings are unfiltered).
    """
    s = settings or EvidenceSettings()
    locked = [gait_locked(r, cutoff_hz) for r in runs]
    rest_parts = [r.resid[r.fit] - r.resid[r.fit].mean(axis=0) - lp for r, lp in zip(runs, locked, strict=False)]
    all_e = np.concatenate([r.resid[r.fit] for r in runs])
    mse = (all_e ** 2).mean(axis=0)
    locked_var = np.concatenate(locked).var(axis=0) if locked else np.zeros(6)
    freqs, psd, dof = rest_spectrum(runs, rest_parts, s)
    floor = spectral_floor(freqs, psd, s.floor_window_hz)
    at_rest = rest_lines(runs, s, lowpass)
    lines = peaks(runs, s, cutoff_hz, at_rest)
    l_ratio, l_p = locked_test(runs, freqs, psd, s, cutoff_hz, tuple(p.frequency_hz for p in lines))
    # the rig's own lines, seen while the leg stands still (those on every run's gait harmonics included)
    lines += [q for q in at_rest if all(abs(q.frequency_hz - p.frequency_hz) > q.width_hz for p in lines)]
    # at rest in still water too (the rig's own), or only where water flows (carried by the flow)
    lines = rest_where(lines, runs, s, lowpass)
    inputs = {"theta_h": [r.theta_h for r in runs], "theta_k": [r.theta_k for r in runs],
              "omega_h": [r.omega_h for r in runs], "omega_k": [r.omega_k for r in runs]}
    if model_force is not None:
        # the model's own force (channel by channel) and its first two derivatives
        inputs["model_force"] = model_force
        inputs["model_force_rate"] = [np.gradient(f, r.dt_s, axis=0) for f, r in zip(model_force, runs, strict=False)]
        inputs["model_force_accel"] = [np.gradient(np.gradient(f, r.dt_s, axis=0), r.dt_s, axis=0)
                                       for f, r in zip(model_force, runs, strict=False)]
    pick = np.unique(np.linspace(0, len(runs) - 1, min(len(runs), s.correlation_runs)).round().astype(int))
    lags, acf, acf_bound, ccf = correlations([runs[i] for i in pick], {k: [v[i] for i in pick]
                                                                        for k, v in inputs.items()}, s)
    by_flow = {}
    for u in sorted({round(r.flow, 3) for r in runs}):
        e = np.concatenate([r.resid[r.fit] for r in runs if round(r.flow, 3) == u])
        by_flow[f"{u:.2f}"] = {ch: float((e[:, c] ** 2).mean()) for c, ch in enumerate(WRENCH_CHANNELS)}
    th = np.concatenate([r.theta_h[r.fit] for r in runs])
    by_angle = _binned(all_e, th, np.linspace(th.min(), th.max() + 1e-9, s.angle_bins + 1))
    phase = np.concatenate([np.mod(r.freq * r.time_s[r.fit], 1.0) if np.isfinite(r.freq) else
                            np.zeros(r.fit.sum()) for r in runs])
    by_phase = _binned(all_e, phase, np.linspace(0, 1, s.phase_bins + 1))
    trend = trend_test(runs, s)
    zero = [r for r in runs if abs(r.flow) < 1e-9]
    zero_flow = {"runs": len(zero)}
    if zero:
        e = np.concatenate([r.resid[r.fit] for r in zero])
        zero_flow["mse"] = {ch: float((e[:, c] ** 2).mean()) for c, ch in enumerate(WRENCH_CHANNELS)}
    rest_runs = [r for r in runs if r.rest.sum() >= 8]
    rest = {"runs": len(rest_runs)}
    if rest_runs:
        e = np.concatenate([r.resid[r.rest][len(r.resid[r.rest]) // 4:] for r in rest_runs])
        rest["mean"] = {ch: float(e[:, c].mean()) for c, ch in enumerate(WRENCH_CHANNELS)}
        rest["std"] = {ch: float(e[:, c].std()) for c, ch in enumerate(WRENCH_CHANNELS)}
    chs = list(WRENCH_CHANNELS)
    return Evidence(
        mse={c: float(mse[i]) for i, c in enumerate(chs)},
        locked_share={c: float(locked_var[i] / max(mse[i], 1e-300)) for i, c in enumerate(chs)},
        locked_ratio={c: float(l_ratio[i]) for i, c in enumerate(chs)},
        locked_p={c: float(l_p[i]) for i, c in enumerate(chs)},
        freqs=freqs, psd_rest=psd, floor=floor, dof=dof, peaks=lines, acf_lags_s=lags, acf=acf,
        acf_bound=acf_bound, ccf=ccf, by_flow=by_flow, by_angle=by_angle, by_phase=by_phase, trend=trend,
        zero_flow=zero_flow, rest=rest)
