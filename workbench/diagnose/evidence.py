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
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal, stats

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

    #: highest frequency examined (Hz); the ingest's low-pass leaves nothing above
    fmax_hz: float = 6.5
    fmin_hz: float = 0.2
    welch_segment_s: float = 8.0
    #: narrowband peak: at least this ratio to the floor and significant at ``peak_alpha`` (Bonferroni over bins)
    peak_ratio: float = 3.0
    peak_alpha: float = 1e-3
    floor_window_hz: float = 1.2
    #: gait-locked power above ``locked_ratio`` times the noise expectation, significant at ``locked_alpha``
    locked_ratio: float = 1.5
    locked_alpha: float = 1e-3
    max_lag_s: float = 1.0
    #: trend (drift) test level and smallest reported share of the residual
    trend_alpha: float = 1e-3
    trend_min_share: float = 0.02
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
                                  "peak_to_floor": {k: r(v) for k, v in p.ratio.items()}} for p in self.peaks],
            "trend_per_s": {c: r(self.trend[c]["slope"]) for c in ch},
            "trend_t": {c: r(self.trend[c]["t"]) for c in ch},
            "mse_by_flow_speed": {k: {c: r(v[c]) for c in ch} for k, v in self.by_flow.items()},
            "zero_flow": self.zero_flow,
            "rest": self.rest,
            "max_abs_ccf_over_bound": {k: {c: r(v["max_ratio"][i]) for i, c in enumerate(ch)}
                                       for k, v in self.ccf.items()},
        }


# ------------------------------------------------------------------------ pieces
def gait_locked(run: RunResidual, cutoff_hz: float) -> np.ndarray:
    """The part of the run's residual (fit ticks) that repeats every stroke: harmonic regression on f."""
    t = run.time_s[run.fit]
    e = run.resid[run.fit]
    if not np.isfinite(run.freq) or run.freq <= 0 or len(t) < 8:
        return np.zeros_like(e)
    k = max(1, int(np.floor(cutoff_hz / run.freq)))
    k = min(k, max(1, (len(t) - 2) // 4))
    w = 2 * np.pi * run.freq * t
    x = np.column_stack([np.ones_like(t)] + [f(j * w) for j in range(1, k + 1) for f in (np.sin, np.cos)])
    coef, *_ = np.linalg.lstsq(x, e, rcond=None)
    locked = x @ coef
    return locked - locked.mean(axis=0)


def _segment(n_ticks: int, dt: float, seconds: float) -> int:
    return int(max(16, min(n_ticks, round(seconds / dt))))


def rest_spectrum(runs: list[RunResidual], parts: list[np.ndarray], s: EvidenceSettings):
    """Welch spectrum of the non-locked residual, averaged over runs; returns freqs, psd, dof."""
    dt = runs[0].dt_s
    lengths = [len(p) for p in parts if len(p) >= 16]
    if not lengths:
        return np.zeros(1), np.zeros((1, 6)), 1.0
    nper = _segment(min(lengths), dt, s.welch_segment_s)
    acc, wsum, nseg = None, 0.0, 0.0
    for p in parts:
        if len(p) < nper:
            continue
        f, pxx = signal.welch(p, fs=1 / dt, nperseg=nper, noverlap=nper // 2, detrend="linear", axis=0)
        segs = 1 + (len(p) - nper) // (nper - nper // 2)
        acc = pxx * segs if acc is None else acc + pxx * segs
        wsum += segs
        nseg += segs
    psd = acc / wsum
    # Hann with 50 % overlap: about 1.9 equivalent independent segments per overlapping pair
    dof = 2.0 * nseg * 0.95
    return f, psd, dof


def spectral_floor(freqs: np.ndarray, psd: np.ndarray, window_hz: float) -> np.ndarray:
    """Running median of the spectrum (a narrow peak does not lift it)."""
    df = freqs[1] - freqs[0] if len(freqs) > 1 else 1.0
    half = max(2, int(round(window_hz / df / 2)))
    out = np.empty_like(psd)
    for i in range(len(freqs)):
        lo, hi = max(0, i - half), min(len(freqs), i + half + 1)
        out[i] = np.median(psd[lo:hi], axis=0)
    return np.maximum(out, 1e-300)


def find_peaks(freqs, psd, floor, dof, s: EvidenceSettings) -> list[Peak]:
    """Narrowband peaks: bins whose ratio to the floor is large and significant, grouped across channels."""
    band = (freqs >= s.fmin_hz) & (freqs <= s.fmax_hz)
    nb = max(1, int(band.sum()))
    ratio = psd / floor
    # Under noise, psd/floor ~ chi2(dof)/dof; Bonferroni over bins and channels.
    crit = stats.chi2.isf(s.peak_alpha / (nb * 6), dof) / dof
    hit = band[:, None] & (ratio >= max(s.peak_ratio, crit))
    peaks: list[Peak] = []
    rows = np.flatnonzero(hit.any(axis=1))
    groups: list[list[int]] = []
    for i in rows:
        if groups and i - groups[-1][-1] <= 1:
            groups[-1].append(i)
        else:
            groups.append([i])
    for g in groups:
        g = np.array(g)
        score = (ratio[g] * hit[g]).max(axis=1)
        i = int(g[np.argmax(score)])
        chans = [WRENCH_CHANNELS[c] for c in range(6) if hit[g, c].any()]
        # parabolic interpolation of the peak in the strongest channel
        c0 = int(np.argmax(ratio[i]))
        fi = freqs[i]
        if 0 < i < len(freqs) - 1:
            y0, y1, y2 = np.log(psd[i - 1:i + 2, c0])
            den = y0 - 2 * y1 + y2
            if den < 0:
                fi = freqs[i] + 0.5 * (y0 - y2) / den * (freqs[1] - freqs[0])
        p = float(stats.chi2.sf(ratio[i, c0] * dof, dof))
        peaks.append(Peak(float(fi), chans, {WRENCH_CHANNELS[c]: float(ratio[g, c].max()) for c in range(6)
                                             if hit[g, c].any()}, p))
    return peaks


def locked_test(runs, locked_parts, freqs, psd, s: EvidenceSettings):
    """Gait-locked power against what noise of the measured floor would put at the harmonics."""
    observed = np.zeros(6)
    expected = np.zeros(6)
    dof = 0.0
    for run, lp in zip(runs, locked_parts):
        t = run.time_s[run.fit]
        if len(t) < 8 or not np.isfinite(run.freq) or run.freq <= 0:
            continue
        dur = len(t) * run.dt_s
        k = max(1, int(np.floor(s.fmax_hz / run.freq)))
        k = min(k, max(1, (len(t) - 2) // 4))
        hf = run.freq * np.arange(1, k + 1)
        # a fitted sinusoid at f takes about 2 S(f) / (2 T) = S(f)/T of the noise variance (one-sided S)
        s_h = np.stack([np.interp(hf, freqs, psd[:, c]) for c in range(6)], axis=1)
        # the remainder lost the 2k+1 fitted degrees of freedom of the band up to k f (of 2 k f T)
        lost = min(0.9, (2 * k + 1) / (2 * k * run.freq * dur))
        expected += s_h.sum(axis=0) / (1 - lost) / dur * len(t)
        observed += (lp ** 2).sum(axis=0)
        dof += 2 * k
    ratio = observed / np.maximum(expected, 1e-300)
    p = stats.chi2.sf(ratio * dof, dof) if dof else np.ones(6)
    return ratio, p


def _acf(x: np.ndarray, max_lag: int) -> np.ndarray:
    x = x - x.mean()
    n = len(x)
    f = np.fft.rfft(x, 2 * n)
    ac = np.fft.irfft(f * np.conj(f))[:max_lag + 1]
    return ac / max(ac[0], 1e-300)


def _ccf(x: np.ndarray, y: np.ndarray, max_lag: int) -> np.ndarray:
    """r_xy(k) = corr(x_t, y_{t+k}) for k = -L..L (y lagging x for k > 0)."""
    x = (x - x.mean()) / (x.std() + 1e-300)
    y = (y - y.mean()) / (y.std() + 1e-300)
    n = len(x)
    full = signal.correlate(y, x, mode="full", method="fft") / n
    mid = n - 1
    return full[mid - max_lag: mid + max_lag + 1]


def correlations(runs: list[RunResidual], inputs: dict[str, list[np.ndarray]], s: EvidenceSettings):
    """Residual autocorrelation and cross-correlations with each input, averaged over runs, with bounds."""
    dt = runs[0].dt_s
    lmax = max(1, int(round(s.max_lag_s / dt)))
    acf_sum = np.zeros((lmax + 1, 6))
    n_tot = 0
    acfs = []
    for run in runs:
        e = run.resid[run.fit]
        if len(e) <= 2 * lmax:
            acfs.append(None)
            continue
        a = np.stack([_acf(e[:, c], lmax) for c in range(6)], axis=1)
        acfs.append(a)
        acf_sum += a * len(e)
        n_tot += len(e)
    acf = acf_sum / max(n_tot, 1)
    bound_white = 2.58 / np.sqrt(max(n_tot, 1))
    ccf = {}
    for name, series in inputs.items():
        r_sum = np.zeros((2 * lmax + 1, 6))
        v_sum = np.zeros((2 * lmax + 1, 6))
        n_sum = 0
        for run, x, a_e in zip(runs, series, acfs):
            if a_e is None:
                continue
            e = run.resid[run.fit]
            xx = np.asarray(x)[run.fit]
            xx = np.repeat(xx[:, None], 6, axis=1) if xx.ndim == 1 else xx
            n = len(e)
            used = False
            for c in range(6):
                if np.std(xx[:, c]) < 1e-12:
                    continue
                a_x = _acf(xx[:, c], lmax)
                # Bartlett: var r_xy(k) ~ (1/n) sum_j rho_xx(j) rho_ee(j) over |j| <= L
                bart = (1 + 2 * (a_x[1:] * a_e[1:, c]).sum()) / n
                r_sum[:, c] += _ccf(xx[:, c], e[:, c], lmax) * n
                v_sum[:, c] += max(bart, 1.0 / n) * n * n
                used = True
            n_sum += n if used else 0
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


def peaks(runs: list[RunResidual], settings: EvidenceSettings | None = None, cutoff_hz: float = 6.0) -> list[Peak]:
    """Only the narrowband peaks of the non-locked residual (what the candidate search needs)."""
    s = settings or EvidenceSettings()
    locked = [gait_locked(r, cutoff_hz) for r in runs]
    rest_parts = [r.resid[r.fit] - r.resid[r.fit].mean(axis=0) - lp for r, lp in zip(runs, locked)]
    freqs, psd, dof = rest_spectrum(runs, rest_parts, s)
    if len(freqs) <= 4:
        return []
    return find_peaks(freqs, psd, spectral_floor(freqs, psd, s.floor_window_hz), dof, s)


def analyse(runs: list[RunResidual], settings: EvidenceSettings | None = None, cutoff_hz: float = 6.0,
            model_force: list[np.ndarray] | None = None) -> Evidence:
    """Evidence from run residuals (analysis ticks)."""
    s = settings or EvidenceSettings()
    locked = [gait_locked(r, cutoff_hz) for r in runs]
    rest_parts = [r.resid[r.fit] - r.resid[r.fit].mean(axis=0) - lp for r, lp in zip(runs, locked)]
    all_e = np.concatenate([r.resid[r.fit] for r in runs])
    mse = (all_e ** 2).mean(axis=0)
    locked_var = np.concatenate(locked).var(axis=0) if locked else np.zeros(6)
    freqs, psd, dof = rest_spectrum(runs, rest_parts, s)
    floor = spectral_floor(freqs, psd, s.floor_window_hz)
    peaks = find_peaks(freqs, psd, floor, dof, s) if len(freqs) > 4 else []
    l_ratio, l_p = locked_test(runs, locked, freqs, psd, s)
    inputs = {"theta_h": [r.theta_h for r in runs], "theta_k": [r.theta_k for r in runs],
              "omega_h": [r.omega_h for r in runs], "omega_k": [r.omega_k for r in runs]}
    if model_force is not None:
        # the model's own force (channel by channel) and its first two derivatives
        inputs["model_force"] = model_force
        inputs["model_force_rate"] = [np.gradient(f, r.dt_s, axis=0) for f, r in zip(model_force, runs)]
        inputs["model_force_accel"] = [np.gradient(np.gradient(f, r.dt_s, axis=0), r.dt_s, axis=0)
                                       for f, r in zip(model_force, runs)]
    lags, acf, acf_bound, ccf = correlations(runs, inputs, s)
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
        freqs=freqs, psd_rest=psd, floor=floor, dof=dof, peaks=peaks, acf_lags_s=lags, acf=acf,
        acf_bound=acf_bound, ccf=ccf, by_flow=by_flow, by_angle=by_angle, by_phase=by_phase, trend=trend,
        zero_flow=zero_flow, rest=rest)
