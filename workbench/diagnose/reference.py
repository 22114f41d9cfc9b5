"""What changed since a reference campaign: the base model's misfit on the reference is not a new effect.

``workbench diagnose --reference REF`` learns, on a reference campaign measured on the same rig,
the base model's **stroke-locked misfit**: each reference run's residual (measured minus the
low-passed prediction) is regressed on the harmonics of its gait phase ``2 pi f t`` (t since
the first trigger edge; a mean and up to ``max_harmonics`` harmonics below the ingest's cutoff),
each modulated by Legendre polynomials of the time in the run up to ``envelope_degree`` (what
settles slowly through a run, such as a circulatory state starting from rest), per channel.
That waveform is indexed by the run's motion parameters and flow speed.

The base model is then corrected run by run: the waveform of the reference run with the same
motion parameters and flow speed (or, failing that, the nearest one in normalised parameter
space, counted) is added to the model's low-passed prediction over the moving part of each run,
before the filter and sensor stages (a mount mode or crosstalk acts on it as on the true wrench).
Its flow sensitivity ``U dW/dU`` (a quadratic in U through the reference waveforms of the same
parameters at every speed) joins the model's wherever the model is asked for its output at
another flow (a flow tone's regressor, the demodulated tone scan). The
diagnosis that follows sees only what differs from the reference: a new servo, load cell, mount
or pump, a drift; the base model's own misfit (which repeats every stroke in both campaigns)
is gone. Rig noise, per-run biases and drifts are not stroke-locked and are not learned.

Limits: the waveform is a function of time in the run, not of the motion: a servo lag that
delays the motion delays the misfit too, which the corrected base does not follow (second
order: the lag times the misfit's rate). Parameter sets the reference lacks get their nearest neighbour's waveform,
which is only as good as the grid is dense.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workbench.contract.columns import TUNNEL_MOTION_PARAMS
from workbench.diagnose.data import Campaign, DataSettings, parameter_key, prepare
from workbench.errors import DataError

#: scales that make motion parameters and flow speed comparable in the nearest-neighbour match
_SCALE = {"theta_h_min_deg": 20.0, "theta_h_max_deg": 20.0, "theta_k_min_deg": 20.0, "theta_k_max_deg": 20.0,
          "frequency_hz": 0.1, "phi_rad": 0.5, "alpha_rad": 0.2}
_FLOW_SCALE = 0.05


@dataclass
class ReferenceCorrection:
    """Per-run stroke-locked waveforms of the base model's misfit on a reference campaign."""

    campaign_id: str
    keys: list[str]                       # parameter key + flow, per reference run
    vectors: np.ndarray                   # (n, d) normalised parameters and flow
    freq: np.ndarray                      # (n,) gait frequency
    coefs: list[np.ndarray]               # (2K+1, 6) per reference run
    max_harmonics: int
    envelope_degree: int
    spans: np.ndarray                     # (n, 2) first and last analysed tick of each reference run (s)
    #: per reference run: (time_s, residual (T, 6)) before its analysed span (rest, ease-in, edge trim)
    heads: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    heldout_mse_share: dict[str, float] = field(default_factory=dict)
    matched: int = 0
    nearest: int = 0

    def summary(self) -> dict:
        """What ``diagnosis.json`` records under ``reference``."""
        return {"campaign": self.campaign_id, "runs": len(self.keys), "max_harmonics": self.max_harmonics,
                "envelope_degree": self.envelope_degree,
                "matched_runs": self.matched, "nearest_neighbour_runs": self.nearest,
                "misfit_share_learned": {k: float(f"{v:.4g}") for k, v in self.heldout_mse_share.items()}}

    def curve(self, i: int, freq: float, time_s: np.ndarray) -> np.ndarray:
        """Reference run ``i``'s misfit (T, 6) at ``time_s`` (s since the first trigger edge).

        Over and after its analysed span: the fitted stroke-locked waveform. Before it (the rest,
        the ease-in and the trimmed first ticks, where no waveform was fitted): the reference's
        own residual, held before its first tick. A filter-stage effect (a mount mode) carries
        what enters it before the analysed span into it; a waveform extrapolated there, or a
        correction that jumps from nothing to the waveform, would ring through the mode and bias
        its damping.
        """
        c = self.coefs[i]
        k = (c.shape[0] // (self.envelope_degree + 1) - 1) // 2
        # the waveform is a function of the stroke phase; a neighbour of another frequency keeps its shape
        f = freq if np.isfinite(freq) and freq > 0 else self.freq[i]
        out = _basis(time_s, f, k, self.envelope_degree, self.spans[i]) @ c
        if i < len(self.heads) and len(self.heads[i][0]):
            th, rh = self.heads[i]
            before = time_s < self.spans[i][0]
            if before.any():
                out[before] = np.column_stack([np.interp(time_s[before], th, rh[:, j]) for j in range(rh.shape[1])])
        return out

    def waveform(self, params: dict, flow: float, freq: float, time_s: np.ndarray) -> tuple[np.ndarray, bool]:
        """Correction (T, 6) for a run, and whether its parameters matched a reference run exactly."""
        key = _key(params, flow)
        exact = key in self.keys
        i = self.keys.index(key) if exact else int(np.argmin(((self.vectors - _vector(params, flow)) ** 2).sum(1)))
        return self.curve(i, freq, time_s), exact

    def flow_sensitivity(self, params: dict, flow: float, freq: float, time_s: np.ndarray) -> np.ndarray | None:
        """``U d(waveform)/dU`` at this run's flow, from the reference runs of its parameters at other speeds.

        A quadratic in U through the waveforms of every speed (a line through two); None when
        the reference has the parameters at one speed only, or the run is at zero flow.
        """
        if flow <= 0:
            return None
        pk = _key(params, flow).split("|")[0]
        idx = [i for i, k in enumerate(self.keys) if k.split("|")[0] == pk]
        if len(idx) < 2:
            return None
        us = np.array([float(self.keys[i].split("|U=")[1]) for i in idx])
        w = np.stack([self.curve(i, freq, time_s) for i in idx])                                   # (n_speeds, T, 6)
        deg = 2 if len(set(us.round(6))) >= 3 else 1
        v = np.vander(us, deg + 1)
        coef = np.linalg.lstsq(v, w.reshape(len(us), -1), rcond=None)[0].reshape(deg + 1, *w.shape[1:])
        d = 2 * coef[0] * flow + coef[1] if deg == 2 else coef[0]
        return flow * d

    def apply(self, campaign: Campaign) -> Campaign:
        """The campaign with each run's reference waveform as a known part of the prediction.

        The waveform is added to the base model's low-passed prediction (``RunSet.offset``), so
        filter and sensor effects (a mount mode, crosstalk) act on it as on the true wrench.
        """
        import dataclasses

        self.matched = self.nearest = 0
        offsets: dict[int, np.ndarray] = {}
        flows: dict[int, np.ndarray] = {}
        for i, r in enumerate(campaign.runs):
            freq = float(r.params.get("frequency_hz", np.nan))
            offsets[i], exact = self.waveform(dict(r.params), float(r.flow_speed_mps), freq, r.time_s)
            g = self.flow_sensitivity(dict(r.params), float(r.flow_speed_mps), freq, r.time_s)
            flows[i] = np.zeros((len(r.time_s), 6)) if g is None else g
            self.matched += int(exact)
            self.nearest += int(not exact)
        def padded(rs, table):
            b, n = rs.shape
            out = np.zeros((b, n, 6))
            for k in range(b):
                o = table[int(rs.index[k])]
                out[k, :len(o)] = o
                out[k, len(o):] = o[-1]
            return out

        sets = [dataclasses.replace(rs, offset=padded(rs, offsets), flow_offset=padded(rs, flows))
                for rs in campaign.train_sets + campaign.heldout_sets]
        nt = len(campaign.train_sets)
        return dataclasses.replace(campaign, train_sets=sets[:nt], heldout_sets=sets[nt:], offsets=offsets,
                                   flow_offsets=flows)


def _key(params: dict, flow: float) -> str:
    return f"{parameter_key(dict(params), 3)}|U={round(float(flow), 3):.3f}"


def _vector(params: dict, flow: float) -> np.ndarray:
    v = [float(params.get(p, 0.0)) / _SCALE.get(p, 1.0) for p in TUNNEL_MOTION_PARAMS]
    return np.array(v + [float(flow) / _FLOW_SCALE])


def _basis(t: np.ndarray, f: float, k: int, degree: int, span) -> np.ndarray:
    """Gait harmonics (mean and k harmonics) times Legendre envelopes of the time in the run.

    The envelopes follow what changes slowly through a run and repeats in every campaign (a
    circulatory state settling over many strokes): a product, so the misfit's shape may change
    along the run. Outside the reference run's analysed span the envelope is held.
    """
    ph = 2 * np.pi * f * t
    harm = [np.ones_like(t)]
    for j in range(1, k + 1):
        harm += [np.cos(j * ph), np.sin(j * ph)]
    h = np.column_stack(harm)
    s = np.clip(2 * (t - span[0]) / max(span[1] - span[0], 1e-9) - 1, -1, 1)
    env = np.polynomial.legendre.legvander(s, degree)
    return (h[:, :, None] * env[:, None, :]).reshape(len(t), -1)


def learn_reference(frame, model, lowpass, fit_settings, data_settings: DataSettings | None = None,
                    cutoff_hz: float = 6.0, max_harmonics: int = 12, envelope_degree: int = 3,
                    source: str = "reference campaign", shrink: bool = True) -> ReferenceCorrection:
    """The base model's stroke-locked misfit on every run of a reference campaign.

    ``shrink``: each harmonic's fitted waveform is shrunk towards zero by the share of its power
    that the reference's own noise would put there (:func:`_shrunk_fit`, noise from the rest
    stretches); without it the reference's noise rides on the corrected model.
    """
    import dataclasses

    from workbench.diagnose.chain import Configuration
    from workbench.diagnose.problem import Problem, run_residuals

    ds = dataclasses.replace(data_settings or DataSettings(), max_runs=0)
    campaign = prepare(frame, ds, source)
    problem = Problem(campaign, model, lowpass, fit_settings)
    base = problem.fit(Configuration(), names=[])
    runs = run_residuals(problem, Configuration(), base)
    psd = noise_psd(runs) if shrink else None
    keys, vecs, freqs, coefs, spans, heads = [], [], [], [], [], []
    sse = np.zeros(6)
    sst = np.zeros(6)
    for r, rm in zip(runs, campaign.runs, strict=False):
        f = r.freq
        if not np.isfinite(f) or f <= 0 or r.fit.sum() < 16:
            continue
        k = int(min(max_harmonics, max(1, np.floor(cutoff_hz / f))))
        t = r.time_s[r.fit]
        span = (float(t.min()), float(t.max()))
        x = _basis(t, f, k, envelope_degree, span)
        e = r.resid[r.fit]
        c = _shrunk_fit(x, e, f, k, envelope_degree + 1, psd)
        params = dict(rm.params)
        keys.append(_key(params, r.flow))
        vecs.append(_vector(params, r.flow))
        freqs.append(f)
        coefs.append(c)
        spans.append(span)
        head = r.time_s < span[0]
        heads.append((r.time_s[head], r.resid[head]))
        sse += ((e - x @ c) ** 2).sum(0)
        sst += (e ** 2).sum(0)
    if not keys:
        raise DataError("no reference run has a gait frequency and enough moving ticks", path=source)
    from workbench.contract.columns import WRENCH_CHANNELS

    share = {ch: float(1 - sse[i] / sst[i]) if sst[i] > 0 else 0.0 for i, ch in enumerate(WRENCH_CHANNELS)}
    return ReferenceCorrection(campaign.campaign_id, keys, np.array(vecs), np.array(freqs), coefs,
                               max_harmonics, envelope_degree, np.array(spans), heads, share)


def noise_psd(runs, quiet_before_s: float = 0.25, min_ticks: int = 24):
    """The rig's noise spectrum per channel from the reference's rest stretches (the leg at rest).

    Each run's residual over its rest ticks (until ``quiet_before_s`` before the first trigger
    edge: the zero-phase low-pass smears the start of the motion back in time) is detrended,
    Hann-windowed and its periodogram, normalised so that white noise of variance s^2 gives s^2
    (the variance of the noise along one unit-norm sinusoid), averaged over runs. Returns
    ``psd(freq_hz) -> (6,)`` or None when no run has ``min_ticks`` rest ticks.
    """
    segs = []
    dt = None
    for r in runs:
        quiet = r.rest & (r.time_s < -quiet_before_s)
        if quiet.sum() >= min_ticks:
            segs.append(r.resid[quiet])
            dt = r.dt_s
    if not segs:
        return None
    n = min(len(x) for x in segs)
    w = np.hanning(n + 2)[1:-1]
    nfft = 4 * int(2 ** np.ceil(np.log2(n)))
    acc = 0.0
    tt = np.arange(n)
    for x in segs:
        x = x[-n:]
        x = x - np.polynomial.polynomial.polyval(tt, np.polynomial.polynomial.polyfit(tt, x, 1)).T
        acc = acc + np.abs(np.fft.rfft(w[:, None] * x, nfft, axis=0)) ** 2
    # detrending removes two directions of n: scale the mean back to the noise's level
    p = acc / len(segs) / np.sum(w * w) * n / max(n - 2, 1)
    freqs = np.fft.rfftfreq(nfft, dt)
    # a few independent estimates per frequency: smooth over about one resolution width
    half = max(1, int(round(0.5 / (n * dt) / (freqs[1] - freqs[0]))))
    ker = np.ones(2 * half + 1) / (2 * half + 1)
    p = np.column_stack([np.convolve(np.pad(p[:, c], half, mode="reflect"), ker, mode="valid")
                         for c in range(p.shape[1])])

    def psd(freq_hz: float) -> np.ndarray:
        return np.array([np.interp(freq_hz, freqs, p[:, c]) for c in range(p.shape[1])])

    return psd


def _shrunk_fit(x: np.ndarray, e: np.ndarray, f: float, k: int, m: int, psd) -> np.ndarray:
    """Coefficients of ``e`` (N, 6) on the basis ``x``, each harmonic's part shrunk by its noise share.

    The waveform learned on the reference carries the reference's noise into the corrected
    model; a filter-stage effect fitted on that model (a mount mode's gain at resonance, a
    crosstalk) is then biased towards attenuation, as any regression on a noisy regressor is. On
    an orthonormal basis of the columns (harmonic by harmonic, ``m`` envelopes each for cos and
    sin), harmonic j's part ``a_j`` is multiplied by ``max(0, 1 - 2 m s_j / |a_j|^2)`` per
    channel (positive-part James-Stein), ``s_j`` the noise's power along one direction at
    ``j f`` (:func:`noise_psd`): a harmonic that stands far above the noise is kept, one at the
    noise's level is dropped. The mean and its envelopes (static misfit, settling) are kept.
    """
    if psd is None:
        c, *_ = np.linalg.lstsq(x, e, rcond=None)
        return c
    q, _ = np.linalg.qr(x)
    a = q.T @ e
    for j in range(1, k + 1):
        rows = slice((2 * j - 1) * m, (2 * j + 1) * m)
        power = (a[rows] ** 2).sum(axis=0)
        share = np.clip(1.0 - 2 * m * psd(j * f) / np.maximum(power, 1e-300), 0.0, 1.0)
        a[rows] *= share
    c, *_ = np.linalg.lstsq(x, q @ a, rcond=None)
    return c
