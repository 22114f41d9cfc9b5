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


# ------------------------------------------------------------------------ pieces
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
    nc = psd.shape[1]
    crit = stats.chi2.isf(s.peak_alpha / (nb * nc), dof) / dof
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
        chans = [WRENCH_CHANNELS[c] for c in range(nc) if hit[g, c].any()]
        # parabolic interpolation of the peak in the strongest channel
        c0 = int(np.argmax(ratio[i]))
        fi = freqs[i]
        if 0 < i < len(freqs) - 1:
            y0, y1, y2 = np.log(psd[i - 1:i + 2, c0])
            den = y0 - 2 * y1 + y2
            if den < 0:
                fi = freqs[i] + 0.5 * (y0 - y2) / den * (freqs[1] - freqs[0])
        p = float(stats.chi2.sf(ratio[i, c0] * dof, dof))
        peaks.append(Peak(float(fi), chans, {WRENCH_CHANNELS[c]: float(ratio[g, c].max()) for c in range(nc)
                                             if hit[g, c].any()}, p))
    return peaks


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
        for run, x, a_e in zip(runs, series, acfs, strict=False):
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


def _near_harmonic(f: float, gait_hz: float, tol_hz: float) -> bool:
    if not np.isfinite(gait_hz) or gait_hz <= 0:
        return False
    k = max(1, round(f / gait_hz))
    return abs(f - k * gait_hz) <= tol_hz


def _scan_grid(dt_s: float, stride: int, step_hz: float, n_max: int) -> tuple[int, float]:
    """FFT length giving bins at most ``step_hz`` apart for every run, and the sampling rate."""
    fs = 1.0 / (dt_s * stride)
    nfft = 1 << int(np.ceil(np.log2(max(fs / step_hz, n_max, 8))))
    return nfft, fs


def line_scan(runs: list[RunResidual], parts: list[np.ndarray], settings: EvidenceSettings, step_hz: float = 0.02):
    """Periodogram of each run's remainder on a fine frequency grid (full-run resolution), summed over runs.

    Each run contributes ``|sum e(t) w(t) exp(-i 2 pi f t)|^2 / sum w^2`` per channel (Hann taper
    ``w``: a strong line's sidelobes, -31 dB, do not pose as lines of their own), so a line keeps
    the resolution 1/T of the whole run, finer than a Welch segment. Zero-padded FFTs at every
    third tick (far above the low-pass cutoff). Returns ``(freqs, scan (F, 6), dof)``.
    """
    stride = 3
    lengths = [len(p[::stride]) for p in parts]
    nfft, fs = _scan_grid(runs[0].dt_s, stride, step_hz, max(lengths, default=8))
    freqs = np.fft.rfftfreq(nfft, 1 / fs)
    band = (freqs >= settings.fmin_hz) & (freqs <= settings.fmax_hz)
    total = np.zeros((int(band.sum()), 6))
    scales = []
    for _run, e in zip(runs, parts, strict=False):
        x = e[::stride]
        if len(x) < 8:
            continue
        taper = np.hanning(len(x) + 2)[1:-1]
        spec = np.fft.rfft(x * taper[:, None], n=nfft, axis=0)[band]
        p = np.abs(spec) ** 2 / (taper ** 2).sum()
        total += p
        scales.append(np.median(p, axis=0))
    if not scales:
        return freqs[band], total, 2.0
    sc = np.asarray(scales)
    dof = float(np.min(2.0 * sc.sum(axis=0) ** 2 / np.maximum((sc ** 2).sum(axis=0), 1e-300)))
    return freqs[band], total, dof


def peaks(runs: list[RunResidual], settings: EvidenceSettings | None = None, cutoff_hz: float = 6.0) -> list[Peak]:
    """Lines in the non-locked residual that are locked to nothing the rig does.

    A line that sits on a gait harmonic of the runs it comes from may be leakage of the
    stroke-locked misfit: each line must stand on its own in the runs whose harmonics miss it.
    """
    s = settings or EvidenceSettings()
    runs = [r for r in runs if r.fit.sum() >= 16]
    if len(runs) < 2:
        return []
    parts = [r.resid[r.fit] - r.resid[r.fit].mean(axis=0) - gait_locked(r, cutoff_hz) for r in runs]
    freqs, scan, dof = line_scan(runs, parts, s)
    found = find_peaks(freqs, scan, spectral_floor(freqs, scan, s.floor_window_hz), dof, s)
    out = []
    for p in found:
        off = [i for i, r in enumerate(runs) if not _near_harmonic(p.frequency_hz, r.freq, harmonic_tolerance(r))]
        if len(off) == len(runs):
            out.append(p)
            continue
        if len(off) < 2:
            continue
        f2, sc2, dof2 = line_scan([runs[i] for i in off], [parts[i] for i in off], s)
        again = find_peaks(f2, sc2, spectral_floor(f2, sc2, s.floor_window_hz), dof2, s)
        if any(abs(q.frequency_hz - p.frequency_hz) <= 0.06 for q in again):
            out.append(p)
    return out


def analyse(runs: list[RunResidual], settings: EvidenceSettings | None = None, cutoff_hz: float = 6.0,
            model_force: list[np.ndarray] | None = None) -> Evidence:
    """Evidence from run residuals (analysis ticks)."""
    s = settings or EvidenceSettings()
    locked = [gait_locked(r, cutoff_hz) for r in runs]
    rest_parts = [r.resid[r.fit] - r.resid[r.fit].mean(axis=0) - lp for r, lp in zip(runs, locked, strict=False)]
    all_e = np.concatenate([r.resid[r.fit] for r in runs])
    mse = (all_e ** 2).mean(axis=0)
    locked_var = np.concatenate(locked).var(axis=0) if locked else np.zeros(6)
    freqs, psd, dof = rest_spectrum(runs, rest_parts, s)
    floor = spectral_floor(freqs, psd, s.floor_window_hz)
    lines = peaks(runs, s, cutoff_hz)
    l_ratio, l_p = locked_test(runs, freqs, psd, s, cutoff_hz, tuple(p.frequency_hz for p in lines))
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


def tone_scan(runs: list[RunResidual], gains: list[np.ndarray], weights: np.ndarray,
              settings: EvidenceSettings | None = None, cutoff_hz: float = 6.0, step_hz: float = 0.02):
    """Scan for a tone carried by the flow: the least-squares gain of ``g(t) sin(2 pi f t + phase_run)``.

    A flow tone enters the force as ``g(t) sin(2 pi f t)`` with ``g = U dF/dU`` swinging with the
    stroke, which spreads it into sidebands that differ run to run, so it hardly shows in a plain
    spectrum. Fitting it with a free phase per run is a demodulation: with ``Z = sum_c w_c g_c r_c``
    and ``G = sum_c w_c g_c^2`` the gain of one run is ``b' A^-1 b`` with ``b`` the Fourier sums of
    ``Z`` and ``A`` those of ``G``. Runs without flow carry no such tone and are left out.
    Returns ``(freqs, scan, dof)``: the summed gain per frequency and its chi-square degrees of freedom.
    """
    s = settings or EvidenceSettings()
    stride = 2   # the scan needs the gain's Fourier sum at twice the frequency
    lengths = [int(r.fit.sum()) // stride + 1 for r in runs]
    nfft, fs = _scan_grid(runs[0].dt_s, stride, step_hz, max(lengths, default=8))
    freqs = np.fft.rfftfreq(nfft, 1 / fs)
    band = np.flatnonzero((freqs >= s.fmin_hz) & (freqs <= s.fmax_hz) & (2 * freqs < fs / 2))
    total = np.zeros(len(band))
    scales = []
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
        scales.append(np.median(gain))
    if not scales:
        return freqs[band], total, 2.0
    sc = np.asarray(scales)
    dof = 2.0 * sc.sum() ** 2 / max((sc ** 2).sum(), 1e-300)
    return freqs[band], total, dof


def flow_tone_peaks(runs: list[RunResidual], gains: list[np.ndarray], weights: np.ndarray,
                    settings: EvidenceSettings | None = None, cutoff_hz: float = 6.0) -> list[Peak]:
    """Peaks of :func:`tone_scan` above its running-median floor (channels: where the flow acts)."""
    s = settings or EvidenceSettings()
    freqs, scan, dof = tone_scan(runs, gains, weights, s, cutoff_hz)
    if not np.any(scan > 0):
        return []
    floor = spectral_floor(freqs, scan[:, None], s.floor_window_hz)
    found = []
    for p in find_peaks(freqs, scan[:, None], floor, dof, s):
        # like a plain line, a flow tone must stand in the runs whose gait harmonics miss it
        off = [i for i, r in enumerate(runs) if not _near_harmonic(p.frequency_hz, r.freq, harmonic_tolerance(r))]
        if len(off) == len(runs):
            found.append(p)
            continue
        if len(off) < 2:
            continue
        f2, sc2, dof2 = tone_scan([runs[i] for i in off], [gains[i] for i in off], weights, s, cutoff_hz)
        if not np.any(sc2 > 0):
            continue
        again = find_peaks(f2, sc2[:, None], spectral_floor(f2, sc2[:, None], s.floor_window_hz), dof2, s)
        if any(abs(q.frequency_hz - p.frequency_hz) <= 0.06 for q in again):
            found.append(p)
    share = np.zeros(6)
    for run, g in zip(runs, gains, strict=False):
        share += (weights * g[run.fit] ** 2).sum(axis=0)
    chans = [WRENCH_CHANNELS[c] for c in range(6) if share[c] >= 0.1 * share.max()]
    return [Peak(p.frequency_hz, chans, {c: p.ratio.get("fx_n", np.nan) for c in chans}, p.p) for p in found]
