"""Unsteady tunnel flow: a tone on the flow speed and its broadband noise (``flow_unsteadiness``; docs/diagnose.md)."""

from __future__ import annotations

import numpy as np

from workbench.diagnose.chain import Active
from workbench.diagnose.effects.base import Context, Effect, SearchParam, Terms
from workbench.diagnose.evidence import flow_tone_peaks, peaks
from workbench.diagnose.evidence_locked import unlocked_share


class FlowUnsteadiness(Effect):
    """U(t) = U (1 + tone_fraction sin(2 pi tone_hz t) + coloured noise of RMS rms_fraction).

    The tone enters as per-run columns ``g(t) sin(2 pi f t)``, ``g(t) cos(2 pi f t)`` with
    ``g = U dF/dU`` measured across the campaign's flow speeds (else the model's ``U dM/dU``; its
    phase in each run is a nuisance fitted per run), optionally stroke-free (:meth:`force_terms`;
    without a reference the line check always fits them so, :meth:`_line_fit`); the tone
    frequency is proposed by a flow-carried line of the residual and refined by search. The noise
    part cannot be predicted; its RMS is estimated from how the residual variance grows with g^2.
    """

    name = "flow_unsteadiness"
    ranges = {"tone_fraction": (0.0, 0.3)}
    physical = False
    formula = "U(t) = U (1 + tone_fraction sin(2 pi tone_hz t) + noise of RMS rms_fraction)"
    search = (SearchParam("tone_hz", (), (0.05, 30.0)),)
    needs_peak = True
    step = 0.05
    # judged over every run, each parameter set held out once (selection_judge.crossfit_judge): its columns are
    # per run, so only the other effects' shared coefficients move between folds. On the split's held-out
    # runs alone, a 1 Hz / 3 % tone under the FED-LSTM reached p 0.012 against the level 0.0005
    crossfit = True

    location_params = ("tone_hz", "rms_fraction")

    def __init__(self, sensitivity: str = "measured", stroke_free: str | bool = "auto"):
        """``sensitivity``: ``measured`` (across the campaign's flow speeds, else the model's) or ``model``.

        ``stroke_free``: project each run's stroke-locked part out of the tone's columns, in the
        runs whose gait harmonics miss the tone (:meth:`force_terms`); ``auto``: when no reference
        campaign has taken the base model's stroke-locked misfit out; ``false`` (default): the
        plain columns ``g sin``, ``g cos`` in every run. Off by default: without a reference the
        held-out test of the stroke-free columns has only the held-out runs whose harmonics miss
        the tone (docs/diagnose.md). The line check uses stroke-free columns without a reference
        whatever this option says (:meth:`check`).
        """
        from workbench.errors import ModelError

        if sensitivity not in ("measured", "model"):
            raise ModelError(f"flow_unsteadiness: sensitivity must be 'measured' or 'model', not {sensitivity!r}")
        if stroke_free not in ("auto", True, False):
            raise ModelError(f"flow_unsteadiness: stroke_free must be auto, true or false, not {stroke_free!r}")
        self.sensitivity = sensitivity
        self.stroke_free = stroke_free
        self._measured: dict = {}
        self._measured_for = None
        self._anchors: list[float] = []
        #: per channel, the share of the step's residual that does not repeat every stroke (:meth:`practical_gain`)
        self._unlocked: np.ndarray | None = None

    def options(self) -> dict:  # noqa: D102
        return {"sensitivity": self.sensitivity, "stroke_free": self.stroke_free}

    def measure(self, problem) -> None:
        """The campaign's measured flow sensitivity (``flowsens.measured_sensitivity``), once per campaign."""
        if self.sensitivity != "measured" or self._measured_for is problem.campaign:
            return
        from workbench.diagnose.flowsens import measured_sensitivity

        self._measured = measured_sensitivity(problem.campaign.sets)
        self._measured_for = problem.campaign

    def gain(self, ctx: Context) -> np.ndarray:
        """The flow sensitivity g = U dF/dU (B, T, 6): measured across the campaign's flow speeds where it can be.

        Runs of a parameter set run at fewer than three speeds (and motions outside the diagnosed
        campaign) take the model's ``U dM/dU`` by a centred difference.
        """
        h = self.step
        g = (ctx.wrench_at_flow(1 + h) - ctx.wrench_at_flow(1 - h)) / (2 * h)
        ids = getattr(ctx.rs, "run_ids", None)
        if not self._measured or ids is None:
            return g
        g = np.array(g, float)
        for i, rid in enumerate(ids):
            hit = self._measured.get(rid)
            if hit is None or abs(float(ctx.rs.flow[i])) < 1e-9:
                continue
            t, gm = hit
            for c in range(6):
                g[i, :, c] = np.interp(ctx.time_s[i], t, gm[:, c])
        return g

    def run_gains(self, problem, config) -> list[np.ndarray]:
        """Per run (index order, valid ticks): g = U dF/dU (measured, else the model's on ``config``'s motion)."""
        self.measure(problem)
        out = {}
        for rs in problem.campaign.sets:
            ctx = problem.context(rs, config)
            if ctx is None:
                motion = rs.motion
                for a in config.stage("input"):
                    motion = a.effect.transform_motion(motion, a.nl)
                ctx = Context(rs, problem.model, motion, problem.geometry)
            # the model at the scaled flows is cached with the batch's context (an LSTM runs once per input)
            g = self.gain(ctx)
            if problem.lowpass is not None:
                g = problem.lowpass(g, rs.dt_s, axis=-2)
            for i in range(rs.shape[0]):
                out[int(rs.index[i])] = g[i, rs.valid[i]]
        return [out[k] for k in sorted(out)]

    def proposals(self, probe, config, fit) -> list:
        """Lines carried by the flow sensitivity first, then the residual's other narrowband lines."""
        self.measure(probe.problem)
        rr = probe.residuals(config, fit)
        self._unlocked = unlocked_share([r for r in rr if abs(r.flow) > 1e-9], probe.cutoff)
        carried = flow_tone_peaks(rr, self.run_gains(probe.problem, config), probe.problem.weights,
                                  probe.settings.evidence, probe.cutoff)
        out = list(carried)
        # then the lines of the flowing runs' rest stretches (a tone on every run's gait harmonics is seen there)
        for p in [*probe.peaks_of(config, fit), *self._rest_lines(probe, [r for r in rr if abs(r.flow) > 1e-9])]:
            if all(abs(p.frequency_hz - q.frequency_hz) > max(0.1, p.width_hz) for q in out):
                out.append(p)
        # the lines the candidates are searched around (which runs sit on a harmonic: _mask_hz)
        self._anchors = sorted({*self._anchors, *(float(p.frequency_hz) for p in out)})
        return out

    @staticmethod
    def _rest_lines(probe, runs: list) -> list:
        """Lines of ``runs``' rest stretches (:func:`evidence.rest_lines`)."""
        from workbench.diagnose.evidence import rest_lines

        return rest_lines(runs, probe.settings.evidence, probe.problem.lowpass)

    def check(self, cand, probe, config, fit) -> str | None:
        """A flow-borne tone is absent at zero flow and removes most of its line (an electrical line stays)."""
        f0 = cand.active.nl["tone_hz"]
        s = probe.settings
        rr = probe.residuals(config, fit)
        zero = [r for r in rr if abs(r.flow) < 1e-9]
        if len(zero) >= 2:
            hit = [p for p in peaks(zero, s.evidence, probe.cutoff) + self._rest_lines(probe, zero)
                   if abs(p.frequency_hz - f0) < p.width_hz]
            if hit:
                where = " (at rest)" if hit[0].at_rest else ""
                return (f"the {f0:.2f} Hz line is there at zero flow too{where} ({', '.join(hit[0].channels)}): "
                        "not carried by the flow")
        after = probe.run_residuals(*self._line_fit(cand, probe))
        left = [p for p in peaks(after, s.evidence, probe.cutoff) if abs(p.frequency_hz - f0) < 0.1]
        if not left:
            return None
        # a flow-borne tone removes most of its line; an electrical line or a vibration stays put.
        # The model's flow sensitivity is only as good as the model, so a remnant may stay.
        def excess(pk) -> float:
            return sum(max(v - 1.0, 0.0) for c, v in pk.ratio.items() if c in pk.channels)

        before = [p for p in peaks(rr, s.evidence, probe.cutoff) if abs(p.frequency_hz - f0) < 0.1]
        eb = max((excess(p) for p in before), default=0.0)
        ea = max(excess(p) for p in left)
        if eb <= 0 or ea > s.selection.tone_line_left * eb:
            return (f"a flow-borne tone leaves the {f0:.2f} Hz line in {', '.join(left[0].channels)} "
                    f"({ea:.0f} of {eb:.0f} excess power ratio)")
        return None

    def _line_fit(self, cand, probe):
        """The configuration and fit whose residual must have lost the tone's line.

        Without a reference the plain columns' per-run amplitude and phase are pulled by the base
        model's stroke-locked misfit (a thousand times the noise on the rich tunnel), which leaves
        part of the line although the tone is carried by the flow. The line is measured on the
        stroke-free remainder, so it is judged after the same tone fitted with stroke-free columns
        (a joint fit with each run's stroke-locked waveform); a vibration or an electrical line
        at that frequency is not carried by ``g`` and stays either way.
        """
        problem = probe.problem
        sets = problem.campaign.sets
        if "stroke_free" in cand.active.nl or not sets or getattr(sets[0], "offset", None) is not None:
            return cand.config, cand.fit
        if self.stroke_free in (True, "auto"):
            return cand.config, cand.fit
        nl = {**cand.active.nl, "stroke_free": 1.0}
        cfg = cand.config.without(self.name).with_effect(Active(self, nl))
        return cfg, problem.fit(cfg, cand.fit.coefs(), cand.names)

    def complete(self, params: dict, stderr: dict, problem, config, residuals: list) -> None:
        """The noise part's RMS, from how the final residual variance grows with g^2."""
        params["rms_fraction"], stderr["rms_fraction"] = flow_noise_rms(
            residuals, self.run_gains(problem, config), problem.weights)

    #: the least share of the residual counted as what a tone can remove (a residual nearly all stroke-locked)
    MIN_UNLOCKED = 0.05

    def practical_gain(self, gain_c: np.ndarray) -> np.ndarray:
        """The gain as a share of the flowing runs' residual that does not repeat every stroke.

        A tone cannot remove the stroke-locked misfit, reported apart as unexplained; under the
        FED-LSTM that is 66-80 % of the rich tunnel's residual, and a 3 % tone at 1 Hz removed 1.1 %
        of the whole (cross-fitted p 1e-8). Taken from the residual of the step's configuration
        (its :meth:`proposals`).
        """
        share = self._unlocked
        if share is None:
            return gain_c
        return gain_c / np.maximum(share, self.MIN_UNLOCKED)

    def explained_frequencies(self, params: dict) -> list[float]:  # noqa: D102
        return [params["tone_hz"]] if params.get("tone_hz") is not None else []

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        return f"a tone at {params.get('tone_hz', float('nan')):.2f} Hz rides on the flow sensitivity of the force"

    #: a run's stroke-free columns must keep this share of the plain ones' power, else they carry no tone
    MIN_FREE_SHARE = 0.25

    #: per-run columns: the tone where the run can tell it from the stroke, and where it cannot
    LOCAL = ("tone_sin", "tone_cos", "tone_sin_h", "tone_cos_h")

    def force_terms(self, ctx: Context, nl: dict) -> Terms:
        """Per-run columns ``g sin``, ``g cos`` of the tone; stroke-free ones where the run can tell it from the stroke.

        Stroke-free (no reference, or option ``true``): in runs whose gait harmonics miss the tone,
        the run's stroke-locked part is projected out of the columns (``flowsens.without_stroke``;
        regressing the residual on them then equals a joint fit with a free stroke-locked
        waveform, so the base model's misfit does not set the tone's amplitude and phase). Runs
        whose harmonics hit the tone carry it in a second pair of columns (``*_h``) that is the
        same in the off-peak null fits (``held_hz``): there the tone cannot be told from the
        stroke-locked misfit, so those runs take no part in the tone's test nor in its fraction,
        but their error is still fitted. Outside a diagnosis (an augmented model predicting a run)
        both pairs carry the tone's own columns, so a run's fitted values predict ``g sin`` itself.
        """
        g = self.gain(ctx)
        ph = 2 * np.pi * nl["tone_hz"] * ctx.time_s
        raw = [g * np.sin(ph)[..., None], g * np.cos(ph)[..., None]]
        rs = ctx.rs
        if not all(hasattr(rs, k) for k in ("fit", "freq")):
            return Terms(local_names=list(self.LOCAL), local=raw + raw)
        zero = np.zeros_like(raw[0])
        if not self._free(rs, nl):
            return Terms(local_names=list(self.LOCAL), local=raw + [zero, zero])
        from workbench.diagnose.flowsens import on_harmonic, without_stroke

        freq = np.asarray(rs.freq, float)
        dur = np.asarray(rs.fit, bool).sum(axis=1) * ctx.dt_s
        hit = on_harmonic(self._mask_hz(nl), freq, dur)[:, None, None]
        if "held_hz" in nl:
            # an off-peak null fit: the runs on a harmonic keep the candidate's own columns
            ph0 = 2 * np.pi * nl["held_hz"] * ctx.time_s
            held = [g * np.sin(ph0)[..., None], g * np.cos(ph0)[..., None]]
        else:
            held = raw
        # every gait harmonic below the low-pass cutoff (a slow gait has more than the evidence's 12)
        # both phases through one projection per run (the basis is the run's, not the column's)
        both = without_stroke(np.concatenate(raw, axis=-1), ctx.time_s, rs.fit, freq, max_harmonics=24)
        free_cols = np.split(both, 2, axis=-1)
        # a run whose harmonics the searched frequency itself hits keeps too little of its columns: what
        # is left (the harmonics' slow change over the run) fits the misfit's, not a tone
        fit = np.asarray(rs.fit, bool)[..., None]
        kept = sum(np.sum(np.where(fit, c, 0.0) ** 2, axis=(1, 2)) for c in free_cols)
        full = sum(np.sum(np.where(fit, c, 0.0) ** 2, axis=(1, 2)) for c in raw)
        gone = (kept < self.MIN_FREE_SHARE * full)[:, None, None]
        return Terms(local_names=list(self.LOCAL),
                     local=[np.where(hit | gone, 0.0, c) for c in free_cols] + [np.where(hit, c, 0.0) for c in held])

    def telling_runs(self, nl: dict, rs) -> np.ndarray | None:  # noqa: D102
        # stroke-free columns: the runs whose gait harmonics miss the candidate's line (force_terms' mask)
        if not all(hasattr(rs, k) for k in ("fit", "freq")) or not self._free(rs, nl):
            return None
        from workbench.diagnose.flowsens import on_harmonic

        dur = np.asarray(rs.fit, bool).sum(axis=1) * rs.dt_s
        return ~on_harmonic(self._mask_hz(nl), np.asarray(rs.freq, float), dur)

    def _free(self, rs, nl: dict) -> bool:
        """Stroke-free columns: ``nl["stroke_free"]`` (the line check's fit) or the option (``auto``: no reference)."""
        if "stroke_free" in nl:
            return bool(nl["stroke_free"])
        if self.stroke_free == "auto":
            return getattr(rs, "offset", None) is None
        return bool(self.stroke_free)

    def _mask_hz(self, nl: dict) -> float:
        """The frequency that decides which runs sit on a gait harmonic: the line the candidate was proposed for.

        Held while the search moves ``tone_hz`` around that line, so that no run changes sides
        during it (a run on a harmonic fits part of the stroke-locked misfit as well, which
        would otherwise pull the search onto gait harmonics).
        """
        if "mask_hz" in nl:
            return float(nl["mask_hz"])
        f = float(nl["tone_hz"])
        near = [a for a in self._anchors if abs(a - f) <= 0.2]
        return min(near, key=lambda a: abs(a - f)) if near else f

    #: off-peak frequencies of the null fits (Hz from the tone): their mean is what a per-run fit gains on
    #: the residual's own spectrum, their spread how much that varies (``selection.judge``)
    NULL_OFFSETS_HZ = (-0.6, -0.45, -0.3, 0.3, 0.45, 0.6)

    def null_variants(self, nl: dict) -> list[dict]:  # noqa: D102
        f = nl["tone_hz"]
        extra = {"stroke_free": nl["stroke_free"]} if "stroke_free" in nl else {}
        # the same runs on a harmonic as the candidate's (its mask, not the searched frequency)
        mask = self._mask_hz(nl)
        return [{"tone_hz": f + d, "mask_hz": mask, "held_hz": f, **extra} for d in self.NULL_OFFSETS_HZ if f + d > 0.05]

    def canonical_params(self, coefs, nl, cov, local=None):  # noqa: D102
        params = {"tone_hz": nl["tone_hz"], "tone_fraction": float("nan"), "rms_fraction": None}
        se = {"tone_hz": float(np.sqrt(max(cov.get(("tone_hz", "tone_hz"), np.nan), 0)))}
        if local:
            # the runs that can tell the tone from the stroke; only where none can, those on a harmonic
            # (their amplitude holds the stroke-locked misfit's share at that harmonic as well)
            ok = np.zeros(0, bool)
            for pair in (("tone_sin", "tone_cos"), ("tone_sin_h", "tone_cos_h")):
                if pair[0] not in local:
                    continue
                a, wa, flow = local[pair[0]]
                b, _, _ = local[pair[1]]
                wa = np.where(flow > 0, wa, 0.0)  # runs without flow carry no tone
                amp = np.hypot(a, b)
                ok = np.isfinite(amp) & (wa > 0)
                if ok.any():
                    break
            if ok.any():
                w = wa[ok] / wa[ok].sum()
                params["tone_fraction"] = float(np.sum(w * amp[ok]))
                se["tone_fraction"] = float(np.sqrt(np.sum(w * (amp[ok] - params["tone_fraction"]) ** 2)
                                                    / max(ok.sum() - 1, 1)))
        return params, se


def flow_noise_rms(runs, gains, weights) -> tuple[float | None, float]:
    """RMS of the flow's unpredictable fluctuation, from how the residual variance grows with g^2.

    With ``U(t) = U (1 + n(t))`` the residual holds ``g n`` (``g = U dF/dU``), so within a run
    ``r_c^2 = a_c + rms^2 g_c^2`` on average; per-run intercepts absorb each run's bias and noise
    level. Channels are pooled with their precision. None when no run has flow.
    """
    terms = []
    for run, g in zip(runs, gains, strict=False):
        if run.flow <= 0 or run.fit.sum() < 16:
            continue
        e2 = run.resid[run.fit] ** 2
        g2 = g[run.fit] ** 2
        x = g2 - g2.mean(axis=0)
        y = e2 - e2.mean(axis=0)
        for c in range(6):
            sxx = float(x[:, c] @ x[:, c])
            if sxx <= 0:
                continue
            terms.append((float(x[:, c] @ y[:, c]) / sxx, sxx, float(np.var(y[:, c])), c))
    if not terms:
        return None, float("nan")
    by_c: dict[int, list] = {}
    for b, sxx, vy, c in terms:
        by_c.setdefault(c, []).append((b, sxx, vy))
    num = den = 0.0
    for rows in by_c.values():
        sxx = sum(r[1] for r in rows)
        b = sum(r[0] * r[1] for r in rows) / sxx
        var_b = max(np.mean([r[2] for r in rows]), 1e-300) / sxx
        num += b / var_b
        den += 1 / var_b
    b = num / den
    rms = float(np.sqrt(max(b, 0.0)))
    se_b = float(np.sqrt(1 / den))
    return rms, (se_b / (2 * rms) if rms > 0 else float("nan"))


LIBRARY_RANK = 3  # place in the library's order (workbench.diagnose.library._in_tree)

EFFECTS = (FlowUnsteadiness,)
