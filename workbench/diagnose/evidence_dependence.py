"""Correlation and dependence evidence: whiteness, cross-correlation with the inputs, bins and drift.

Autocorrelation of the residual with white-noise bounds; cross-correlation with the inputs (joint
angles and rates, the model's force and its derivatives) over lags, with Bartlett's bounds (valid
for two coloured but independent signals); the residual binned against an input (joint angle,
stroke phase); and the pooled within-run slope against time (a drift) with a between-run t-test.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose.evidence_base import EvidenceSettings, RunResidual


def _spectra(x: np.ndarray, nfft: int) -> tuple[np.ndarray, np.ndarray]:
    """Autocorrelations (lag 0 = 1) of the columns of ``x`` (n, k), and their scaled spectra.

    The spectra at ``nfft`` points (``nfft >= 2n``), after scaling to unit variance (a constant column
    stays zero).
    """
    z = x - x.mean(axis=0)
    f = np.fft.rfft(z, nfft, axis=0)
    ac = np.fft.irfft(f * np.conj(f), nfft, axis=0)
    sd = z.std(axis=0)
    return ac / np.maximum(ac[0], 1e-300), f / np.where(sd > 0, sd, 1.0)


def _lags(c: np.ndarray, lmax: int) -> np.ndarray:
    """Lags -L..L of a circular correlation computed without wrap-around (``nfft >= 2n - 1``)."""
    return np.concatenate([c[len(c) - lmax:], c[:lmax + 1]])


def correlations(runs: list[RunResidual], inputs: dict[str, list[np.ndarray]], s: EvidenceSettings):
    """Residual autocorrelation and cross-correlations with each input, averaged over runs, with bounds.

    One FFT of each run's residual and of each input, all six channels at once (until 1 Dec 2026 one
    ``scipy.signal.correlate`` per run, input and channel: 3,000 of them in a diagnosis, the same numbers
    to 1e-15).
    """
    dt = runs[0].dt_s
    lmax = max(1, int(round(s.max_lag_s / dt)))
    acf_sum = np.zeros((lmax + 1, 6))
    n_tot = 0
    spectra = []
    for run in runs:
        e = run.resid[run.fit]
        n = len(e)
        if n <= 2 * lmax:
            spectra.append(None)
            continue
        ac, fe = _spectra(e, 2 * n)
        a = ac[:lmax + 1]
        spectra.append((a, fe, n))
        acf_sum += a * n
        n_tot += n
    acf = acf_sum / max(n_tot, 1)
    bound_white = 2.58 / np.sqrt(max(n_tot, 1))
    ccf = {}
    for name, series in inputs.items():
        r_sum = np.zeros((2 * lmax + 1, 6))
        v_sum = np.zeros((2 * lmax + 1, 6))
        n_sum = 0
        for run, x, spec in zip(runs, series, spectra, strict=False):
            if spec is None:
                continue
            a_e, fe, n = spec
            nfft = 2 * n
            xx = np.asarray(x)[run.fit]
            xx = xx[:, None] if xx.ndim == 1 else xx  # one input for every channel: one FFT
            live = np.broadcast_to(np.std(xx, axis=0) >= 1e-12, (6,))
            if not live.any():
                continue
            ax, fx = _spectra(xx, nfft)
            a_x = ax[:lmax + 1]
            # r_xy(k) = corr(x_t, e_{t+k}): the residual lags the input for k > 0
            r = _lags(np.fft.irfft(fe * np.conj(fx), nfft, axis=0), lmax) / n
            # Bartlett: var r_xy(k) ~ (1/n) sum_j rho_xx(j) rho_ee(j) over |j| <= L
            bart = (1 + 2 * (a_x[1:] * a_e[1:]).sum(axis=0)) / n
            r_sum[:, live] += r[:, live] * n
            v_sum[:, live] += np.maximum(bart[live], 1.0 / n) * n * n
            n_sum += n
        if n_sum == 0:
            continue
        r = r_sum / n_sum
        bound = 2.58 * np.sqrt(v_sum) / n_sum
        ccf[name] = {"lags_s": dt * np.arange(-lmax, lmax + 1), "r": r, "bound": bound,
                     "max_ratio": (np.abs(r) / np.maximum(bound, 1e-12)).max(axis=0)}
    return dt * np.arange(lmax + 1), acf, bound_white, ccf


def _binned(values: np.ndarray, x: np.ndarray, edges: np.ndarray) -> dict:
    idx = np.clip(np.digitize(x, edges) - 1, 0, len(edges) - 2)
    mse = np.full((len(edges) - 1, 6), np.nan)
    mean = np.full((len(edges) - 1, 6), np.nan)
    for i in range(len(edges) - 1):
        m = idx == i
        if m.sum() >= 4:
            mse[i] = (values[m] ** 2).mean(axis=0)
            mean[i] = values[m].mean(axis=0)
    return {"centers": 0.5 * (edges[1:] + edges[:-1]), "mse": mse, "mean": mean}


def trend_test(runs: list[RunResidual], s: EvidenceSettings) -> dict[str, dict]:
    """Pooled within-run slope of the residual against time (a drift), with a between-run t-test."""
    out = {}
    slopes = []
    for run in runs:
        t = run.time_s[run.fit]
        e = run.resid[run.fit]
        if len(t) < 16:
            continue
        tc = t - t.mean()
        sxx = (tc ** 2).sum()
        slopes.append(((tc[:, None] * (e - e.mean(axis=0))).sum(axis=0) / sxx, sxx, np.var(e, axis=0), np.ptp(t)))
    for c, ch in enumerate(WRENCH_CHANNELS):
        if len(slopes) < 3:
            out[ch] = {"slope": float("nan"), "t": 0.0, "p": 1.0, "share": 0.0}
            continue
        b = np.array([x[0][c] for x in slopes])
        w = np.array([x[1] for x in slopes])
        mean = float(np.sum(w * b) / np.sum(w))
        se = float(np.sqrt(np.sum(w ** 2 * (b - mean) ** 2)) / np.sum(w) * np.sqrt(len(b) / (len(b) - 1)))
        tval = mean / se if se > 0 else 0.0
        var_e = np.mean([x[2][c] for x in slopes])
        dur = np.mean([x[3] for x in slopes])
        share = (mean * dur) ** 2 / 12 / max(var_e, 1e-300)
        out[ch] = {"slope": mean, "t": tval, "p": float(2 * stats.t.sf(abs(tval), df=len(b) - 1)),
                   "share": float(share)}
    return out
