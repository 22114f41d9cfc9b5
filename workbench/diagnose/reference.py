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
    heldout_mse_share: dict[str, float] = field(default_factory=dict)
    matched: int = 0
    nearest: int = 0

    def summary(self) -> dict:
        """What ``diagnosis.json`` records under ``reference``."""
        return {"campaign": self.campaign_id, "runs": len(self.keys), "max_harmonics": self.max_harmonics,
                "envelope_degree": self.envelope_degree,
                "matched_runs": self.matched, "nearest_neighbour_runs": self.nearest,
                "misfit_share_learned": {k: float(f"{v:.4g}") for k, v in self.heldout_mse_share.items()}}

    def waveform(self, params: dict, flow: float, freq: float, time_s: np.ndarray) -> tuple[np.ndarray, bool]:
        """Correction (T, 6) for a run, and whether its parameters matched a reference run exactly."""
        key = _key(params, flow)
        exact = key in self.keys
        i = self.keys.index(key) if exact else int(np.argmin(((self.vectors - _vector(params, flow)) ** 2).sum(1)))
        c = self.coefs[i]
        k = (c.shape[0] // (self.envelope_degree + 1) - 1) // 2
        # the waveform is a function of the stroke phase; a neighbour of another frequency keeps its shape
        f = freq if np.isfinite(freq) and freq > 0 else self.freq[i]
        return _basis(time_s, f, k, self.envelope_degree, self.spans[i]) @ c, exact

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
        ws = []
        for i in idx:
            c = self.coefs[i]
            k = (c.shape[0] // (self.envelope_degree + 1) - 1) // 2
            f = freq if np.isfinite(freq) and freq > 0 else self.freq[i]
            ws.append(_basis(time_s, f, k, self.envelope_degree, self.spans[i]) @ c)
        w = np.stack(ws)                                   # (n_speeds, T, 6)
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
            moving = r.time_s >= 0
            freq = float(r.params.get("frequency_hz", np.nan))
            w, exact = self.waveform(dict(r.params), float(r.flow_speed_mps), freq, r.time_s[moving])
            off = np.zeros((len(r.time_s), 6))
            off[moving] = w
            offsets[i] = off
            g = self.flow_sensitivity(dict(r.params), float(r.flow_speed_mps), freq, r.time_s[moving])
            dg = np.zeros((len(r.time_s), 6))
            if g is not None:
                dg[moving] = g
            flows[i] = dg
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
                    source: str = "reference campaign") -> ReferenceCorrection:
    """The base model's stroke-locked misfit on every run of a reference campaign."""
    import dataclasses

    from workbench.diagnose.chain import Configuration
    from workbench.diagnose.problem import Problem, run_residuals

    ds = dataclasses.replace(data_settings or DataSettings(), max_runs=0)
    campaign = prepare(frame, ds, source)
    problem = Problem(campaign, model, lowpass, fit_settings)
    base = problem.fit(Configuration(), names=[])
    runs = run_residuals(problem, Configuration(), base)
    keys, vecs, freqs, coefs, spans = [], [], [], [], []
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
        c, *_ = np.linalg.lstsq(x, e, rcond=None)
        params = dict(rm.params)
        keys.append(_key(params, r.flow))
        vecs.append(_vector(params, r.flow))
        freqs.append(f)
        coefs.append(c)
        spans.append(span)
        sse += ((e - x @ c) ** 2).sum(0)
        sst += (e ** 2).sum(0)
    if not keys:
        raise DataError("no reference run has a gait frequency and enough moving ticks", path=source)
    from workbench.contract.columns import WRENCH_CHANNELS

    share = {ch: float(1 - sse[i] / sst[i]) if sst[i] > 0 else 0.0 for i, ch in enumerate(WRENCH_CHANNELS)}
    return ReferenceCorrection(campaign.campaign_id, keys, np.array(vecs), np.array(freqs), coefs,
                               max_harmonics, envelope_degree, np.array(spans), share)
