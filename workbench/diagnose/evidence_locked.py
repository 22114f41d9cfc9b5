"""Gait-locked evidence: the part of the residual that repeats every stroke, and its power test.

Each run's residual is split by harmonic regression on its gait frequency (harmonics up to the
low-pass cutoff) into the stroke-locked part and the rest. A model error of the fluid physics
repeats every stroke; noise, drift, a pump tone or electrical pickup do not. :func:`locked_test`
weighs the power at the gait harmonics against what noise of the measured floor would put
there, after discounting run-to-run clock jitter and the harmonics that fall on a known line.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from workbench.diagnose.evidence_base import EvidenceSettings, RunResidual

#: harmonics of the gait in the stroke-locked part (a stroke's misfit lives in its first few)
MAX_HARMONICS = 12


def _harmonic_fit(run: RunResidual, cutoff_hz: float):
    """Harmonic regression of the run's residual on its gait frequency: (k, amplitudes^2 (k, 6), locked part).

    Cached on the run (a residual is analysed several times per step).
    """
    cache = run.__dict__.setdefault("_locked", {})
    if cutoff_hz in cache:
        return cache[cutoff_hz]
    t = run.time_s[run.fit]
    e = run.resid[run.fit]
    if not np.isfinite(run.freq) or run.freq <= 0 or len(t) < 8:
        cache[cutoff_hz] = (0, np.zeros((0, 6)), np.zeros_like(e))
        return cache[cutoff_hz]
    k = max(1, int(np.floor(cutoff_hz / run.freq)))
    k = min(k, max(1, (len(t) - 2) // 4), MAX_HARMONICS)
    w = 2 * np.pi * run.freq * (t - t[0])
    j = np.arange(1, k + 1)
    x = np.concatenate([np.ones((len(t), 1)), np.sin(np.outer(w, j)), np.cos(np.outer(w, j))], axis=1)
    g = x.T @ x
    coef = np.linalg.solve(g + 1e-9 * np.trace(g) / len(g) * np.eye(len(g)), x.T @ e)
    locked = x @ coef
    amp2 = coef[1:k + 1] ** 2 + coef[k + 1:] ** 2
    cache[cutoff_hz] = (k, amp2, locked - locked.mean(axis=0))
    return cache[cutoff_hz]


def gait_locked(run: RunResidual, cutoff_hz: float) -> np.ndarray:
    """The part of the run's residual (fit ticks) that repeats every stroke."""
    return _harmonic_fit(run, cutoff_hz)[2]


def harmonic_tolerance(run: RunResidual) -> float:
    """How close (Hz) a frequency must be to a gait harmonic to be confused with it in this run."""
    return 0.8 / max(run.fit.sum() * run.dt_s, 1e-9)


def _harmonic_amp2(run: RunResidual, e: np.ndarray, k: int) -> np.ndarray:
    """Squared amplitudes (k, 6) of the first k gait harmonics of ``e`` (fit ticks)."""
    t = run.time_s[run.fit]
    w = 2 * np.pi * run.freq * (t - t[0])
    j = np.arange(1, k + 1)
    x = np.concatenate([np.ones((len(t), 1)), np.sin(np.outer(w, j)), np.cos(np.outer(w, j))], axis=1)
    g = x.T @ x
    coef = np.linalg.solve(g + 1e-9 * np.trace(g) / len(g) * np.eye(len(g)), x.T @ e)
    return coef[1:k + 1] ** 2 + coef[k + 1:] ** 2


def _clock_jitter(runs: list[RunResidual], cutoff_hz: float) -> dict[int, np.ndarray]:
    """Per-run timing misalignment: the residual part ``(delta_r - median delta) dF/dt`` of each run.

    Ingest aligns clocks on trigger edges sampled at the load cell's rate, which leaves each run
    off by a fraction of a millisecond; the residual then holds ``delta_r`` times the force's
    rate, locked to the stroke but not a model error. Only the run-to-run scatter is discounted:
    a delay common to all runs (a servo lag) stays in the residual.
    """
    deltas, rates = {}, {}
    for run in runs:
        if run.fit.sum() < 16:
            continue
        e = run.resid[run.fit]
        d = np.gradient(run.predicted, run.dt_s, axis=0)[run.fit]
        w = 1.0 / np.maximum(e.var(axis=0), 1e-300)
        den = float((w * d * d).sum())
        if den <= 0:
            continue
        deltas[run.index] = float((w * e * d).sum()) / den
        rates[run.index] = d
    if len(deltas) < 3:
        return {}
    med = float(np.median(list(deltas.values())))
    return {i: -(deltas[i] - med) * rates[i] for i in deltas}


def locked_test(runs, freqs, psd, s: EvidenceSettings, cutoff_hz: float = 6.0, lines: tuple[float, ...] = ()):
    """Gait-locked power against what noise of the measured floor would put at the harmonics.

    Harmonics that fall on a known residual line (``lines``) are left out: that power is the line's.
    """
    observed = np.zeros(6)
    expected = np.zeros(6)
    dof = 0.0
    jitter = _clock_jitter(runs, cutoff_hz)
    for run in runs:
        t = run.time_s[run.fit]
        k, amp2, _ = _harmonic_fit(run, cutoff_hz)
        if k == 0:
            continue
        if run.index in jitter:
            amp2 = _harmonic_amp2(run, run.resid[run.fit] + jitter[run.index], k)
        dur = len(t) * run.dt_s
        hf = run.freq * np.arange(1, k + 1)
        tol = harmonic_tolerance(run)
        keep = np.array([all(abs(h - f) > tol for f in lines) for h in hf])
        if not keep.any():
            continue
        # a fitted sinusoid at f takes about S(f)/T of the noise power per sample (one-sided S)
        s_h = np.stack([np.interp(hf, freqs, psd[:, c]) for c in range(6)], axis=1)
        # the remainder lost the 2k+1 fitted degrees of freedom of the band up to k f (of 2 k f T)
        lost = min(0.9, (2 * k + 1) / (2 * k * run.freq * dur))
        expected += s_h[keep].sum(axis=0) / (1 - lost) / dur * len(t)
        observed += amp2[keep].sum(axis=0) / 2 * len(t)
        dof += 2 * keep.sum()
    ratio = observed / np.maximum(expected, 1e-300)
    p = stats.chi2.sf(ratio * dof, dof) if dof else np.ones(6)
    return ratio, p
