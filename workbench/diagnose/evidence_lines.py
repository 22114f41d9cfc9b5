"""Spectral evidence: the Welch spectrum of the non-locked residual and its narrowband lines.

The rest of the residual (what does not repeat every stroke) is averaged into a Welch spectrum;
narrowband peaks are found by their ratio to a running-median floor, with a chi-square test at
the spectrum's degrees of freedom. :func:`peaks` scans each run at full-run resolution and keeps
only lines locked to nothing the rig does (every run has its own gait frequency; a line on a
gait harmonic must stand on its own in the runs whose harmonics miss it).
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy import signal, stats

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose.evidence_base import EvidenceSettings, Peak, RunResidual
from workbench.diagnose.evidence_locked import gait_locked, harmonic_tolerance

#: the line scan takes every third tick (a 65 Hz reading: lines to 10.8 Hz)
SCAN_STRIDE = 3


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
    n, width = len(freqs), 2 * half + 1
    out = np.empty_like(psd)
    edges = range(n) if n < width else [*range(half), *range(n - half, n)]
    for i in edges:  # near the ends the window is cut short
        lo, hi = max(0, i - half), min(n, i + half + 1)
        out[i] = np.median(psd[lo:hi], axis=0)
    if n >= width:  # the full windows at once, in blocks of about 4 M values (the median copies its input)
        windows = np.lib.stride_tricks.sliding_window_view(psd, width, axis=0)
        step = max(1, (1 << 22) // max(1, width * int(np.prod(psd.shape[1:]))))
        for a in range(0, len(windows), step):
            block = np.median(windows[a:a + step], axis=-1)
            out[half + a:half + a + len(block)] = block
    return np.maximum(out, 1e-300)


def find_peaks(freqs, psd, floor, dof, s: EvidenceSettings) -> list[Peak]:
    """Narrowband peaks: bins whose ratio to the floor is large and significant, grouped across channels.

    ``dof``: the spectrum's chi-square degrees of freedom, one number or one per frequency.
    """
    band = (freqs >= s.fmin_hz) & (freqs <= s.fmax_hz)
    nb = max(1, int(band.sum()))
    ratio = psd / floor
    dof = np.broadcast_to(np.asarray(dof, float), np.shape(freqs))
    # Under noise, psd/floor ~ chi2(dof)/dof; Bonferroni over bins and channels.
    nc = psd.shape[1]
    crit = stats.chi2.isf(s.peak_alpha / (nb * nc), dof) / dof
    hit = band[:, None] & (ratio >= np.maximum(s.peak_ratio, crit)[:, None])
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
        if _beyond_band(ratio[:, c0], band, i):
            # still rising at the band's edge: the maximum is outside it (the skirt of something above)
            continue
        fi = freqs[i]
        if 0 < i < len(freqs) - 1:
            y0, y1, y2 = np.log(psd[i - 1:i + 2, c0])
            den = y0 - 2 * y1 + y2
            if den < 0:
                fi = freqs[i] + 0.5 * (y0 - y2) / den * (freqs[1] - freqs[0])
        p = float(stats.chi2.sf(ratio[i, c0] * dof[i], dof[i]))
        peaks.append(Peak(float(fi), chans, {WRENCH_CHANNELS[c]: float(ratio[g, c].max()) for c in range(nc)
                                             if hit[g, c].any()}, p))
    return peaks


def _beyond_band(ratio: np.ndarray, band: np.ndarray, i: int) -> bool:
    """Whether bin ``i``, the best of a group at the band's edge, rises on into the bins past the edge."""
    for step in (1, -1):
        j = i + step
        if 0 <= j < len(ratio) and not band[j] and ratio[j] >= ratio[i]:
            return True
    return False


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

    The scan reaches half a floor window past ``fmin_hz`` and ``fmax_hz`` (:func:`find_peaks` looks
    for lines between them only), so the running-median floor is two-sided at the band's ends:
    cut at ``fmax_hz``, the rising skirt of something above the band (a FED-LSTM's clean demo copy:
    tx power rising to 8.1 Hz) stood 5x over a one-sided floor and read as "a line at 6.50 Hz".
    """
    stride = SCAN_STRIDE
    lengths = [len(p[::stride]) for p in parts]
    nfft, fs = _scan_grid(runs[0].dt_s, stride, step_hz, max(lengths, default=8))
    freqs = np.fft.rfftfreq(nfft, 1 / fs)
    margin = 0.5 * settings.floor_window_hz
    band = (freqs > 0) & (freqs >= settings.fmin_hz - margin) & (freqs <= settings.fmax_hz + margin)
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


def peaks(runs: list[RunResidual], settings: EvidenceSettings | None = None, cutoff_hz: float = 6.0,
          rest: list[Peak] = ()) -> list[Peak]:
    """Lines in the non-locked residual that are locked to nothing the rig does.

    A line that sits on a gait harmonic of the runs it comes from may be leakage of the
    stroke-locked misfit: each line must stand on its own in the runs whose harmonics miss it.
    Lines that are another line's stroke sidebands are marked (:func:`mark_sidebands`; ``rest``:
    the lines at rest, which tell the carrier).
    """
    s = settings or EvidenceSettings()
    # lines are looked for past the low-pass cutoff, to ``lines_fmax_hz`` (within the scan's Nyquist frequency)
    runs = [r for r in runs if r.fit.sum() >= 16]
    if len(runs) < 2:
        return []
    s = dataclasses.replace(s, fmax_hz=_lines_fmax(s, runs[0].dt_s))
    parts = [r.resid[r.fit] - r.resid[r.fit].mean(axis=0) - gait_locked(r, cutoff_hz) for r in runs]
    freqs, scan, dof = line_scan(runs, parts, s)
    found = find_peaks(freqs, scan, spectral_floor(freqs, scan, s.floor_window_hz), dof, s)

    def rescan(off: list[int]) -> list[Peak]:
        f2, sc2, dof2 = line_scan([runs[i] for i in off], [parts[i] for i in off], s)
        return find_peaks(f2, sc2, spectral_floor(f2, sc2, s.floor_window_hz), dof2, s)

    return mark_sidebands(stand_off_harmonics(found, runs, rescan), runs, rescan, rest)


def _lines_fmax(s: EvidenceSettings, dt_s: float) -> float:
    """The line scan's top: ``lines_fmax_hz``, at least ``fmax_hz``, and half a floor window under the scan's Nyquist frequency."""
    nyquist = 0.5 / (dt_s * SCAN_STRIDE)
    return float(max(s.fmax_hz, min(s.lines_fmax_hz, nyquist - 0.5 * s.floor_window_hz)))


#: the shortest rest stretch (s) a run's rest lines are scanned from
MIN_REST_S = 0.5


def _rested(runs: list[RunResidual], min_rest_s: float = MIN_REST_S) -> list[RunResidual]:
    """The runs with at least ``min_rest_s`` of rest before they move."""
    return [r for r in runs if r.rest.sum() * r.dt_s >= min_rest_s]


def rest_lines(runs: list[RunResidual], settings: EvidenceSettings | None = None,
               lowpass=None, min_rest_s: float = MIN_REST_S,
               step_hz: float = 0.02) -> list[Peak]:
    """Lines in the rest stretches before the runs start moving: the rig's own vibration.

    A pump, a fan or a mount mode shakes the readings while the leg stands still; the stroke's
    misfit is not there yet. So a line at rest is the rig's even where it sits on a gait harmonic
    of every run, which the moving scan (:func:`peaks`) cannot tell from the stroke (a 6 Hz
    vibration is the 10th to 20th harmonic of 0.3-0.6 Hz strokes). Each run's rest residual is
    detrended, Hann-tapered and its periodogram summed over runs. A rest stretch of T seconds
    resolves 1/T (its main lobe spans +-2/T), so the floor at each frequency is the median of
    the spectrum outside that lobe (2/T to 2/T + 1 Hz away on either side), taken on the
    spectrum divided by the ingest's low-pass (``lowpass``: the problem's ``chain.Lowpass``, its
    cutoff and order; None: unfiltered readings) and multiplied back: near the cutoff the filter's
    fall would otherwise pose as a floor. Peaks are found from 1/T to ``fmax_hz`` (the floor
    reaches 1 Hz beyond) and kept from 2/T up: below, a line is not resolved, and a strong one
    there (a 1 Hz tone) spreads into the bins above, where its group's top is not. Runs with at
    least ``min_rest_s`` of rest; none when fewer than two have one. On the clean rich tunnel
    (36 rest seconds) no bin stands 1.9x above the floor; a 6 Hz vibration of 8 mN stands 120x.
    """
    from scipy import signal as sig

    s = settings or EvidenceSettings()
    parts = [(r, r.resid[r.rest]) for r in _rested(runs, min_rest_s)]
    if len(parts) < 2:
        return []
    dt = parts[0][0].dt_s
    t_rest = min(len(x) for _, x in parts) * dt
    nfft = 1 << int(np.ceil(np.log2(max(1.0 / (dt * step_hz), max(len(x) for _, x in parts)))))
    freqs = np.fft.rfftfreq(nfft, dt)
    keep = (freqs >= 1.0 / t_rest) & (freqs <= min(s.fmax_hz + 1.0, 0.45 / dt))
    f = freqs[keep]
    total = np.zeros((len(f), 6))
    scales = []
    for _r, x in parts:
        x = sig.detrend(x, axis=0)
        taper = np.hanning(len(x) + 2)[1:-1]
        p = np.abs(np.fft.rfft(x * taper[:, None], n=nfft, axis=0)[keep]) ** 2 / (taper ** 2).sum()
        total += p
        scales.append(np.median(p, axis=0))
    sc = np.asarray(scales)
    dof = float(np.min(2.0 * sc.sum(axis=0) ** 2 / np.maximum((sc ** 2).sum(axis=0), 1e-300)))
    gain = np.ones(len(f)) if lowpass is None else lowpass.power_gain(f, dt)
    white = total / gain[:, None]
    floor = np.empty_like(total)
    gap = 2.0 / t_rest
    for i, fi in enumerate(f):
        d = np.abs(f - fi)
        side = (d >= gap) & (d <= gap + 1.0)
        floor[i] = np.median(white[side], axis=0) * gain[i] if side.any() else total[i]
    # peaks over all resolved bins, kept from 2/T up: a strong line below (a 1 Hz tone) spreads its lobe
    # into the lowest bins kept, and its group's top lies below them
    band = (f >= max(s.fmin_hz, 1.0 / t_rest)) & (f <= s.fmax_hz)
    if not band.any():
        return []
    found = find_peaks(f[band], total[band], np.maximum(floor[band], 1e-300), dof, s)
    return [Peak(p.frequency_hz, p.channels, p.ratio, p.p, at_rest=True, width_hz=max(0.1, 0.5 / t_rest))
            for p in found if p.frequency_hz >= gap]


def stand_off_harmonics(found: list[Peak], runs: list[RunResidual], rescan, tol_hz: float = 0.06) -> list[Peak]:
    """The peaks of ``found`` that stand in the runs whose gait harmonics miss them.

    A peak that sits on no run's gait harmonic is kept; one on some runs' harmonics may be leakage
    of the stroke-locked misfit, so it is kept only when ``rescan(off)`` (the same scan over the
    run indices ``off`` whose harmonics miss it, at least two) finds a peak within ``tol_hz``.
    """
    out = []
    for p in found:
        off = [i for i, r in enumerate(runs) if not _near_harmonic(p.frequency_hz, r.freq, harmonic_tolerance(r))]
        if len(off) == len(runs):
            out.append(p)
        elif len(off) >= 2 and any(abs(q.frequency_hz - p.frequency_hz) <= tol_hz for q in rescan(off)):
            out.append(p)
    return out


def mark_sidebands(lines: list[Peak], runs: list[RunResidual], rescan, rest=(), max_order: int = 6,
                   tol_hz: float = 0.06) -> list[Peak]:
    """Mark the motion scan's lines that are another line's sidebands from the stroke.

    A disturbance that the stroke modulates (a flow tone loads the leg by how fast it moves through
    the water, ``a sin(2 pi f0 t) U dF/dU`` with ``dF/dU`` changing over the stroke) puts lines at
    ``f0 +- k f_g`` beside its own in each run of gait frequency ``f_g``. Each would be reported as
    one more unexplained line; it is one disturbance. Carriers are taken first: a line a rest line
    (``rest``) lies on (the nearest within the rest line's width: a sideband needs the stroke), then
    a line with lines ``k f_g`` away on both sides, then the strongest (a sideband may stand above
    its carrier: a flow tone's mean ``dF/dU`` over a stroke can be small beside its swing). A line
    ``k f_g`` (k = 1 .. ``max_order``, within ``tol_hz``) from a carrier for some runs' ``f_g`` is
    that carrier's sideband unless it stands on its own in the other runs (``rescan(off)``, the same
    scan over the run indices ``off`` whose gait frequencies put no sideband of the carrier there, at
    least two): a second vibration 0.4 Hz above the first is in every run, a sideband only in the
    runs at 0.4 Hz (or 0.2, 0.133 Hz). Marked lines get ``sideband_of`` = the carrier's frequency.
    """
    from dataclasses import replace

    if len(lines) < 2:
        return list(lines)

    def sideband_runs(d_hz: float) -> list[int]:
        return [i for i, r in enumerate(runs)
                if np.isfinite(r.freq) and r.freq > 0
                and any(abs(d_hz - k * r.freq) <= tol_hz for k in range(1, max_order + 1))]

    def apart(a: Peak, b: Peak) -> bool:
        return bool(sideband_runs(abs(a.frequency_hz - b.frequency_hz)))

    # the motion lines nearest to a rest line, kept where a rest line lies within its width
    nearest = {min(range(len(lines)), key=lambda i: abs(lines[i].frequency_hz - q.frequency_hz)) for q in rest}
    on_rest = {i for i in nearest if any(abs(lines[i].frequency_hz - q.frequency_hz) <= q.width_hz for q in rest)}

    def rank(i: int):
        p = lines[i]
        below = sum(apart(p, q) for q in lines if q.frequency_hz < p.frequency_hz)
        above = sum(apart(p, q) for q in lines if q.frequency_hz > p.frequency_hz)
        return (i not in on_rest, -min(below, above), -max(p.ratio.values(), default=0.0))

    def carrier_of(p: Peak, carriers: list[Peak]) -> Peak | None:
        # the first carrier p lies k f_g from, unless p stands on its own in the runs that put no sideband there
        for c in carriers:
            on = set(sideband_runs(abs(p.frequency_hz - c.frequency_hz)))
            off = [j for j in range(len(runs)) if j not in on]
            if on and not (len(off) >= 2 and any(abs(q.frequency_hz - p.frequency_hz) <= tol_hz
                                                 for q in rescan(off))):
                return c
        return None

    carriers: list[Peak] = []
    marked: dict[int, float] = {}
    for i in sorted(range(len(lines)), key=rank):
        hit = None if i in on_rest else carrier_of(lines[i], carriers)
        if hit is None:
            carriers.append(lines[i])
        else:
            marked[i] = hit.frequency_hz
    return [replace(p, sideband_of=marked[i]) if i in marked else p for i, p in enumerate(lines)]


def rest_where(lines: list[Peak], runs: list[RunResidual], settings: EvidenceSettings | None = None,
               lowpass=None) -> list[Peak]:
    """Each line marked with where the rest stretches show it (``Peak.rest_seen``).

    The rest stretches of the still-water runs and of the flowing runs are scanned apart
    (:func:`rest_lines`): a line there in still water too is the rig's own (a pump, a fan, a
    mount); one there only where water flows is carried by the flow (a pump's pulsation, vortex
    shedding upstream). "rest": seen at rest, with fewer than two still-water rest stretches to
    tell. A line matches a rest line within the wider of the two's widths.
    """
    from dataclasses import replace

    s = settings or EvidenceSettings()
    flowing = [r for r in runs if abs(r.flow) > 1e-9]
    still = [r for r in runs if abs(r.flow) <= 1e-9]
    at_flow, at_still = rest_lines(flowing, s, lowpass), rest_lines(still, s, lowpass)
    can_tell = len(_rested(still)) >= 2  # rest_lines needs two rest stretches

    def near(p: Peak, found: list[Peak]) -> bool:
        return any(abs(q.frequency_hz - p.frequency_hz) <= max(q.width_hz, p.width_hz) for q in found)

    out = []
    for p in lines:
        in_flow, in_still = near(p, at_flow), near(p, at_still)
        seen = ("still" if in_still else "flow" if in_flow and can_tell else
                "rest" if in_flow or p.at_rest else "")
        out.append(replace(p, rest_seen=seen) if seen else p)
    return out
