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


#: degree of the Legendre envelope a stroke's strongest harmonics may carry over a run (1: they may grow or
#: shrink linearly). A stroke's misfit is not stationary: a learned model's builds up over the first
#: strokes and slips as the motion eases out (the FED-LSTM's fundamental on the demo campaign: 0.005 N
#: in a run's first fifth, 0.038-0.05 N after). Removed at a constant amplitude, the change leaks into
#: +-2/T of the harmonic, and summed over the runs of one gait frequency that stood 4.6x over the floor
#: as "a line at 0.53 Hz" in every FED-LSTM diagnosis without a reference.
ENVELOPE_DEGREE = 1
#: the harmonics holding at least this share of the run's strongest harmonic's power (in some channel) ...
ENVELOPE_SHARE = 0.1
#: ... the lowest this many of them get the envelope. An envelope takes in part of a real line within about
#: 2/T of its harmonic: on every strong harmonic, a 1 Hz flow tone between a 0.3 Hz stroke's 0.9 and 1.2 Hz
#: harmonics kept 6 of its line's 15 excess power ratio after its fit and was refused.
ENVELOPE_ORDERS = 1


def _harmonic_design(run: RunResidual, t: np.ndarray, k: int, degree: int = 0,
                     enveloped: np.ndarray | None = None, base: np.ndarray | None = None) -> np.ndarray:
    """Columns of the harmonic regression: the mean and k harmonics, then envelopes.

    The ``enveloped`` harmonics (orders from 1) times the Legendre polynomials of the run's time
    of degree 1 to ``degree``. ``base``: this run's design of degree 0 already made (its columns are
    reused, not computed again).
    """
    if base is None:
        w = 2 * np.pi * run.freq * (t - t[0])
        j = np.arange(1, k + 1)
        base = np.concatenate([np.ones((len(t), 1)), np.sin(np.outer(w, j)), np.cos(np.outer(w, j))], axis=1)
    if degree < 1 or enveloped is None or len(enveloped) == 0 or len(t) < 2:
        return base
    sub = np.asarray(enveloped, int)
    u = 2 * (t - t[0]) / max(t[-1] - t[0], 1e-12) - 1
    env = np.polynomial.legendre.legvander(u, degree)[:, 1:]
    h = np.concatenate([base[:, sub], base[:, k + sub]], axis=1)
    return np.concatenate([base] + [h * env[:, [d]] for d in range(env.shape[1])], axis=1)


def _solve(x: np.ndarray, e: np.ndarray) -> np.ndarray:
    g = x.T @ x
    return np.linalg.solve(g + 1e-9 * np.trace(g) / len(g) * np.eye(len(g)), x.T @ e)


def _harmonic_fit(run: RunResidual, cutoff_hz: float):
    """Harmonic regression of the run's residual on its gait frequency: (k, amplitudes^2 (k, 6), locked part).

    The amplitudes are those of constant harmonics (what :func:`locked_test` weighs); in the locked
    part the lowest strong harmonic may drift over the run (:data:`ENVELOPE_DEGREE`), so a misfit that
    builds up over the first strokes does not leak beside it into the line scans. A drift of the
    readings is no harmonic: it stays in the remainder. Cached on the run (a residual is analysed
    several times per step).
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
    x0 = _harmonic_design(run, t, k)
    coef = _solve(x0, e)
    amp2 = coef[1:k + 1] ** 2 + coef[k + 1:] ** 2
    rel = amp2 / np.maximum(amp2.max(axis=0), 1e-300)
    strong = np.flatnonzero((rel >= ENVELOPE_SHARE).any(axis=1))[:ENVELOPE_ORDERS] + 1
    x = _harmonic_design(run, t, k, ENVELOPE_DEGREE, strong, base=x0)
    locked = x @ _solve(x, e) if x.shape[1] > x0.shape[1] and len(t) > 4 * x.shape[1] else x0 @ coef
    cache[cutoff_hz] = (k, amp2, locked - locked.mean(axis=0))
    return cache[cutoff_hz]


def gait_locked(run: RunResidual, cutoff_hz: float) -> np.ndarray:
    """The part of the run's residual (fit ticks) that repeats every stroke (its amplitude may drift slowly)."""
    return _harmonic_fit(run, cutoff_hz)[2]


def unlocked_share(runs: list[RunResidual], cutoff_hz: float) -> np.ndarray:
    """Per channel, the share of the runs' residual power (fit ticks) left once each run's level and stroke-locked part are out.

    What a disturbance that does not repeat every stroke (a flow tone) can at most remove.
    """
    total, rest = np.zeros(6), np.zeros(6)
    for r in runs:
        if r.fit.sum() < 16:
            continue
        e = r.resid[r.fit]
        total += (e * e).sum(axis=0)
        d = e - e.mean(axis=0) - gait_locked(r, cutoff_hz)
        rest += (d * d).sum(axis=0)
    return np.where(total > 0, rest / np.maximum(total, 1e-300), 1.0)


def harmonic_tolerance(run: RunResidual) -> float:
    """How close (Hz) a frequency must be to a gait harmonic to be confused with it in this run."""
    return 0.8 / max(run.fit.sum() * run.dt_s, 1e-9)


def _harmonic_amp2(run: RunResidual, e: np.ndarray, k: int) -> np.ndarray:
    """Squared amplitudes (k, 6) of the first k gait harmonics of ``e`` (fit ticks)."""
    coef = _solve(_harmonic_design(run, run.time_s[run.fit], k), e)
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
