"""Flow-tone evidence: a tone carried by the flow, found by demodulating the residual with the flow gain.

A tone in the free stream enters the force as ``g(t) sin(2 pi f t)`` with ``g = U dF/dU``
swinging with the stroke, so it spreads into sidebands and hardly shows in a plain spectrum.
:func:`tone_scan` fits it with a free phase per run; :func:`flow_tone_peaks` keeps the scan's
peaks above its running-median floor that stand in runs whose gait harmonics miss them.
"""

from __future__ import annotations

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose.evidence_base import EvidenceSettings, Peak, RunResidual
from workbench.diagnose.evidence_lines import _scan_grid, find_peaks, spectral_floor, stand_off_harmonics
from workbench.diagnose.evidence_locked import gait_locked


def tone_scan(runs: list[RunResidual], gains: list[np.ndarray], weights: np.ndarray,
              settings: EvidenceSettings | None = None, cutoff_hz: float = 6.0, step_hz: float = 0.02):
    """Scan for a tone carried by the flow: the least-squares gain of ``g(t) sin(2 pi f t + phase_run)``.

    A flow tone enters the force as ``g(t) sin(2 pi f t)`` with ``g = U dF/dU`` swinging with the
    stroke, which spreads it into sidebands that differ run to run, so it hardly shows in a plain
    spectrum. Fitting it with a free phase per run is a demodulation: with ``Z = sum_c w_c g_c r_c``
    and ``G = sum_c w_c g_c^2`` the gain of one run is ``b' A^-1 b`` with ``b`` the Fourier sums of
    ``Z`` and ``A`` those of ``G``. Runs without flow carry no such tone and are left out.
    Returns ``(freqs, scan, dof)``: the summed gain per frequency and its chi-square degrees of
    freedom per frequency. Under noise a run's gain is its own noise level times chi2(2)/2, so the
    sum has Satterthwaite's ``2 (sum s_r)^2 / sum s_r^2`` degrees of freedom with ``s_r`` each run's
    level at that frequency (the running median of its own scan): the residual's colour differs run
    to run, and one level per run over the whole band (its median) counted a 1 Hz tone's 24 flowing
    runs as 12 and refused a 3 % tone under the FED-LSTM.
    """
    s = settings or EvidenceSettings()
    stride = 2   # the scan needs the gain's Fourier sum at twice the frequency
    lengths = [int(r.fit.sum()) // stride + 1 for r in runs]
    nfft, fs = _scan_grid(runs[0].dt_s, stride, step_hz, max(lengths, default=8))
    freqs = np.fft.rfftfreq(nfft, 1 / fs)
    band = np.flatnonzero((freqs >= s.fmin_hz) & (freqs <= s.fmax_hz) & (2 * freqs < fs / 2))
    total = np.zeros(len(band))
    levels = []
    for run, g in zip(runs, gains, strict=False):
        gg = g[run.fit]
        if not np.any(np.abs(gg) > 0) or run.fit.sum() < 16:
            continue
        e = run.resid[run.fit]
        e = e - e.mean(axis=0) - gait_locked(run, cutoff_hz)
        z = (weights * gg * e).sum(axis=1)[::stride]
        big = (weights * gg * gg).sum(axis=1)[::stride]
        taper = np.hanning(len(z) + 2)[1:-1]      # tapered (weighted) least squares: low sidelobes
        zf = np.fft.rfft(z * taper, n=nfft)
        gf = np.fft.rfft(big * taper, n=nfft)
        s0 = float((big * taper).sum())
        b1, b2 = -zf.imag[band], zf.real[band]                  # sum z sin, sum z cos
        c2, s2 = gf.real[2 * band], -gf.imag[2 * band]          # sum G cos 2wt, sum G sin 2wt
        a11, a22, a12 = (s0 - c2) / 2, (s0 + c2) / 2, s2 / 2
        det = np.maximum(a11 * a22 - a12 ** 2, 1e-300)
        gain = (a22 * b1 ** 2 - 2 * a12 * b1 * b2 + a11 * b2 ** 2) / det
        total += gain
        levels.append(gain)
    if not levels:
        return freqs[band], total, 2.0
    local = spectral_floor(freqs[band], np.stack(levels, axis=1), s.floor_window_hz)   # (F, runs)
    dof = 2.0 * local.sum(axis=1) ** 2 / np.maximum((local ** 2).sum(axis=1), 1e-300)
    return freqs[band], total, dof


def flow_tone_peaks(runs: list[RunResidual], gains: list[np.ndarray], weights: np.ndarray,
                    settings: EvidenceSettings | None = None, cutoff_hz: float = 6.0) -> list[Peak]:
    """Peaks of :func:`tone_scan` above its running-median floor (channels: where the flow acts)."""
    s = settings or EvidenceSettings()
    freqs, scan, dof = tone_scan(runs, gains, weights, s, cutoff_hz)
    if not np.any(scan > 0):
        return []
    floor = spectral_floor(freqs, scan[:, None], s.floor_window_hz)

    def rescan(off: list[int]) -> list[Peak]:
        f2, sc2, dof2 = tone_scan([runs[i] for i in off], [gains[i] for i in off], weights, s, cutoff_hz)
        if not np.any(sc2 > 0):
            return []
        return find_peaks(f2, sc2[:, None], spectral_floor(f2, sc2[:, None], s.floor_window_hz), dof2, s)

    # like a plain line, a flow tone must stand in the runs whose gait harmonics miss it
    found = stand_off_harmonics(find_peaks(freqs, scan[:, None], floor, dof, s), runs, rescan)
    share = np.zeros(6)
    for run, g in zip(runs, gains, strict=False):
        share += (weights * g[run.fit] ** 2).sum(axis=0)
    chans = [WRENCH_CHANNELS[c] for c in range(6) if share[c] >= 0.1 * share.max()]
    return [Peak(p.frequency_hz, chans, {c: p.ratio.get("fx_n", np.nan) for c in chans}, p.p) for p in found]
