"""Candidate effects of the rig: servo, tunnel, structure and load cell (canonical names; docs/diagnose.md).

These act on what the leg is commanded to do (servo lag), on the flow it meets (blockage,
unsteadiness) or on how its load is read (resonance, crosstalk, drift). Only the servo lag is
part of the physical leg handed to the simulator; the others belong to the tunnel and load cell.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose.chain import Active
from workbench.diagnose.effects.base import Context, Effect, SearchParam, Terms
from workbench.diagnose.evidence import ccf_clause, flow_tone_peaks, peaks
from workbench.hydro.motion import LegMotion

SHORT = tuple(c.split("_")[0] for c in WRENCH_CHANNELS)  # fx, fy, fz, tx, ty, tz


def lag_filter(x: np.ndarray, tau_s: float, dt_s: float, axis: int = -1) -> np.ndarray:
    """First-order low-pass (time constant ``tau_s``) along ``axis``, starting at rest on the first sample.

    Exact for an input that is linear between samples (first-order hold), so the 65 Hz control
    ticks follow the continuous lag closely.
    """
    if tau_s <= 0:
        return np.array(x, float)
    e = np.exp(-dt_s / tau_s)
    g = tau_s * (1 - e) / dt_s
    b, a = np.array([1 - g, g - e]), np.array([1.0, -e])
    x = np.asarray(x, float)
    ax = axis % x.ndim
    x0 = np.take(x, [0], axis=ax)
    zi = signal.lfilter_zi(b, a).reshape([-1 if i == ax else 1 for i in range(x.ndim)]) * x0
    y, _ = signal.lfilter(b, a, x, axis=ax, zi=zi)
    return y


def dead_time(x: np.ndarray, delay_s: float, dt_s: float, axis: int = -1) -> np.ndarray:
    """``x`` delayed by ``delay_s`` along ``axis`` (4-point Lagrange fractional delay; the first sample held before).

    Accurate to about 1e-3 of the amplitude at 6 Hz on 65 Hz ticks (a linear interpolation loses
    several per cent there).
    """
    x = np.asarray(x, float)
    if delay_s <= 0:
        return np.array(x, float)
    d = delay_s / dt_s
    k = int(np.floor(d))
    u = 1.0 - (d - k)                      # the target lies u ticks after sample n - k - 1
    w = (-u * (u - 1) * (u - 2) / 6, (u + 1) * (u - 1) * (u - 2) / 2, -(u + 1) * u * (u - 2) / 2,
         (u + 1) * u * (u - 1) / 6)
    n = x.shape[axis]
    idx = np.arange(n) - k - 1
    out = np.zeros_like(x)
    for j, wj in zip((-1, 0, 1, 2), w, strict=True):
        out += wj * np.take(x, np.clip(idx + j, 0, n - 1), axis=axis)
    return out


class ServoLag(Effect):
    """Actual joint angles = the commanded angles after a dead time and a first-order lag, both joints.

    Searched as the effective delay ``tau_s`` (dead time plus lag: the phase every harmonic sees
    at low frequency) and the share of it that is dead time. A pure first-order lag of a 60 ms
    dead time attenuates a stroke's 6 Hz harmonics to 40 %, and the force effects then take the
    misfit; a dead time with a lag fits a servo of any mix. ``shapes`` (option): ``lag`` (only a
    first-order lag, the share fixed at 0) or ``dead+lag`` (default).
    """

    name = "servo_lag"
    ranges = {"tau_s": (0.0, 0.3)}
    stage = "input"
    formula = "theta = theta_cmd(t - dead_s) / (1 + lag_s s), both joints; tau_s = dead_s + lag_s"
    TAU = SearchParam("tau_s", (0.005, 0.012, 0.02, 0.03, 0.04, 0.055, 0.075, 0.1, 0.14, 0.2), (0.0005, 0.4), log=True)
    SHARE = SearchParam("dead_share", (0.0, 0.5, 1.0), (0.0, 1.0))
    search = (TAU, SHARE)
    surrogate_ok = True
    lookahead = True
    #: the split of tau_s between dead time and lag locates the servo's shape, it does not measure its size
    location_params = ("dead_share", "dead_s", "lag_s")

    def __init__(self, shapes: str = "dead+lag"):
        if shapes not in ("lag", "dead+lag"):
            from workbench.errors import ModelError

            raise ModelError(f"servo_lag: shapes must be 'lag' or 'dead+lag', not {shapes!r}")
        self.shapes = shapes
        self.search = (self.TAU, self.SHARE) if shapes == "dead+lag" else (self.TAU,)

    def options(self) -> dict:  # noqa: D102
        return {"shapes": self.shapes}

    @staticmethod
    def split(nl: dict) -> tuple[float, float]:
        """(dead time, lag) in seconds from the searched values (a saved ``{"tau_s": x}`` is a pure lag)."""
        tau = float(nl["tau_s"])
        share = float(np.clip(nl.get("dead_share", 0.0), 0.0, 1.0))
        return tau * share, tau * (1.0 - share)

    def canonical_params(self, coefs, nl, cov, local=None):  # noqa: D102
        params, se = super().canonical_params(coefs, nl, cov, local)
        if "tau_s" in nl:
            params["dead_s"], params["lag_s"] = self.split(nl)
        return params, se

    def on_output(self, w: np.ndarray, dt_s: float, nl: dict) -> np.ndarray:
        """A causal model's output through the same dead time and lag (first order in tau)."""
        dead, lag = self.split(nl)
        return lag_filter(dead_time(w, dead, dt_s, axis=-2), lag, dt_s, axis=-2)

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        return ccf_clause(ev, "model_force_rate", "the rate of the model's force")

    def transform_motion(self, motion: LegMotion, nl: dict) -> LegMotion:  # noqa: D102
        dead, tau = self.split(nl)
        dt = motion.dt_s
        if tau <= 0 and dead <= 0:
            return motion
        # angles, rates and accelerations through the same (linear) delay and lag: the lag of a
        # derivative is the derivative of the lag, and filtering each keeps the 65 Hz error at 1e-4
        ah, ak = motion.accelerations_dps2()
        f = (lambda a: lag_filter(dead_time(a, dead, dt), tau, dt))  # noqa: E731
        return LegMotion(dt, f(motion.theta_h_deg), f(motion.theta_k_deg), f(motion.omega_h_dps),
                         f(motion.omega_k_dps), motion.flow_speed_mps, f(ah), f(ak))


class TunnelBlockage(Effect):
    """Free-stream dynamic pressure raised by (1 + epsilon): U_eff = U sqrt(1 + epsilon).

    Acts on the flow every term sees (the model, a drag error, lift, ...), like the tunnel does;
    epsilon is found by a 1-D search wrapping the linear fit.
    """

    name = "tunnel_blockage"
    ranges = {"epsilon": (-0.1, 0.5)}
    stage = "input"
    physical = False
    formula = "U_eff = U sqrt(1 + epsilon)"
    search = (SearchParam("epsilon", (-0.06, -0.02, 0.02, 0.05, 0.08, 0.12, 0.18, 0.3), (-0.5, 1.5)),)
    surrogate_ok = True

    def __init__(self, test_section_area_m2: float | None = None, theta: float = 2.5, c_d: float = 1.17,
                 prior_width: float = 0.5):
        """``test_section_area_m2``: the tunnel's cross-section; given, epsilon takes Maskell's prior.

        With a cross-section each run's blockage is Maskell's ``theta C_D S_run / C``
        (``workbench.diagnose.maskell``) times ``1 + d_maskell``, one factor for the campaign,
        fitted by least squares with the Gaussian prior ``d_maskell ~ N(0, prior_width^2)`` (a ridge
        toward Maskell's value). Without one, nothing changes: one epsilon, searched.
        """
        if test_section_area_m2 is not None and not (float(test_section_area_m2) > 0):
            from workbench.errors import ModelError

            raise ModelError(f"tunnel_blockage: test_section_area_m2 must be positive, got {test_section_area_m2!r}")
        if not (theta > 0 and c_d > 0 and prior_width > 0):
            from workbench.errors import ModelError

            raise ModelError("tunnel_blockage: theta, c_d and prior_width must be positive")
        self.area = None if test_section_area_m2 is None else float(test_section_area_m2)
        self.theta, self.c_d, self.prior_width = float(theta), float(c_d), float(prior_width)
        self._eps: dict[str, float] = {}
        if self.area is not None:
            self.stage, self.search, self.surrogate_ok = "force", (), False
            self.formula = "U_eff = U sqrt(1 + epsilon_run), epsilon_run = (1 + d_maskell) theta C_D S_run / C"

    def options(self) -> dict:  # noqa: D102
        if self.area is None:
            return {}
        return {"test_section_area_m2": self.area, "theta": self.theta, "c_d": self.c_d,
                "prior_width": self.prior_width}

    def linear_names(self):  # noqa: D102
        return ["d_maskell"] if self.area is not None else []

    def priors(self) -> dict[str, tuple[float, float]]:
        """Gaussian priors (mean, sd) of linear parameters: Maskell's factor, when a cross-section is known."""
        return {"d_maskell": (0.0, self.prior_width)} if self.area is not None else {}

    def force_terms(self, ctx: Context, nl: dict) -> Terms:  # noqa: D102
        if self.area is None:
            return Terms()
        from workbench.diagnose.maskell import blockage_terms, prior_epsilon, run_flow

        eps = prior_epsilon(ctx, self.area, self.theta, self.c_d)
        for rid, e, u in zip(getattr(ctx.rs, "run_ids", ()), eps, run_flow(ctx), strict=False):
            if u > 0:
                self._eps[rid] = float(e)
        fixed, col = blockage_terms(ctx, eps)
        return Terms(["d_maskell"], [col], [np.ones(6, bool)], fixed=fixed)

    def canonical_params(self, coefs, nl, cov, local=None):  # noqa: D102
        if self.area is None:
            return super().canonical_params(coefs, nl, cov, local)
        from workbench.diagnose.maskell import data_alone

        prior = float(np.mean(list(self._eps.values()))) if self._eps else float("nan")
        d = float(coefs.get("d_maskell", 0.0))
        var = float(cov.get(("d_maskell", "d_maskell"), np.nan))
        params = {"epsilon": prior * (1 + d), "epsilon_prior": prior, "epsilon_prior_sd": prior * self.prior_width,
                  "epsilon_data": None, "d_maskell": d}
        se = {"epsilon": abs(prior) * float(np.sqrt(max(var, 0.0))) if np.isfinite(var) else float("nan")}
        alone = data_alone(d, var, self.prior_width)
        if alone is not None:
            params["epsilon_data"] = prior * (1 + alone[0])
        return params, se

    def flow_factor(self, nl: dict) -> float:
        """U_eff / U."""
        if self.area is not None:
            return 1.0
        return float(np.sqrt(max(1.0 + nl["epsilon"], 1e-6)))

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        worst = max(ev.by_flow, key=lambda k: float(k)) if ev.by_flow else None
        return f"the misfit grows with flow speed (fy MSE {ev.by_flow[worst]['fy_n']:.3g} at {worst} m/s)" if worst else ""

    def transform_motion(self, motion: LegMotion, nl: dict) -> LegMotion:  # noqa: D102
        if self.area is not None:
            return motion
        f = self.flow_factor(nl)
        return LegMotion(motion.dt_s, motion.theta_h_deg, motion.theta_k_deg, motion.omega_h_dps,
                         motion.omega_k_dps, motion.flow_speed_mps * f, motion.alpha_h_dps2, motion.alpha_k_dps2)


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

    location_params = ("tone_hz", "rms_fraction")

    def __init__(self, sensitivity: str = "measured", stroke_free: str | bool = False):
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
        carried = flow_tone_peaks(rr, self.run_gains(probe.problem, config), probe.problem.weights,
                                  probe.settings.evidence, probe.cutoff)
        out = list(carried)
        for p in probe.peaks_of(config, fit):
            if all(abs(p.frequency_hz - q.frequency_hz) > 0.1 for q in out):
                out.append(p)
        # the lines the candidates are searched around (which runs sit on a harmonic: _mask_hz)
        self._anchors = sorted({*self._anchors, *(float(p.frequency_hz) for p in out)})
        return out

    def check(self, cand, probe, config, fit) -> str | None:
        """A flow-borne tone is absent at zero flow and removes most of its line (an electrical line stays)."""
        f0 = cand.active.nl["tone_hz"]
        s = probe.settings
        rr = probe.residuals(config, fit)
        zero = [r for r in rr if abs(r.flow) < 1e-9]
        if len(zero) >= 2:
            hit = [p for p in peaks(zero, s.evidence, probe.cutoff) if abs(p.frequency_hz - f0) < 0.1]
            if hit:
                return (f"the {f0:.2f} Hz line is there at zero flow too ({', '.join(hit[0].channels)}): "
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

    def explained_frequencies(self, params: dict) -> list[float]:  # noqa: D102
        return [params["tone_hz"]] if params.get("tone_hz") is not None else []

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        return f"a tone at {params.get('tone_hz', float('nan')):.2f} Hz rides on the flow sensitivity of the force"

    #: per-run columns: the tone where the run can tell it from the stroke, and where it cannot
    LOCAL = ("tone_sin", "tone_cos", "tone_sin_h", "tone_cos_h")

    def force_terms(self, ctx: Context, nl: dict) -> Terms:
        """Per-run columns ``g sin``, ``g cos`` of the tone; stroke-free ones where the run can tell it from the stroke.

        Stroke-free (no reference, or option ``true``): in runs whose gait harmonics miss the tone,
        the run's stroke-locked part is projected out of the columns (``flowsens.without_stroke``;
        regressing the residual on them then equals a joint fit with a free stroke-locked
        waveform, so the base model's misfit does not set the tone's amplitude and phase). Runs
        whose harmonics hit the tone carry it in a second pair of columns (``*_h``) that is the
        same in the off-peak null fits (``mask_hz``): there the tone cannot be told from the
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
        if "mask_hz" in nl:
            # an off-peak null fit: the runs on a harmonic keep the candidate's own columns
            ph0 = 2 * np.pi * nl["mask_hz"] * ctx.time_s
            held = [g * np.sin(ph0)[..., None], g * np.cos(ph0)[..., None]]
        else:
            held = raw
        # every gait harmonic below the low-pass cutoff (a slow gait has more than the evidence's 12)
        free_cols = [without_stroke(c, ctx.time_s, rs.fit, freq, max_harmonics=24) for c in raw]
        return Terms(local_names=list(self.LOCAL),
                     local=[np.where(hit, 0.0, c) for c in free_cols] + [np.where(hit, c, 0.0) for c in held])

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

    def null_variants(self, nl: dict) -> list[dict]:  # noqa: D102
        f = nl["tone_hz"]
        extra = {"stroke_free": nl["stroke_free"]} if "stroke_free" in nl else {}
        return [{"tone_hz": f + d, "mask_hz": f, **extra} for d in (-0.35, 0.35) if f + d > 0.05]

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


def _mode_coefficients(f_n_hz: float, zeta: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear discretisation of wn^2 / (s^2 + 2 zeta wn s + wn^2), prewarped at wn (exact there)."""
    wn = 2 * np.pi * f_n_hz
    k = wn / np.tan(wn * dt_s / 2)
    a0 = k * k + 2 * zeta * wn * k + wn * wn
    b = np.array([wn * wn, 2 * wn * wn, wn * wn]) / a0
    a = np.array([1.0, (2 * wn * wn - 2 * k * k) / a0, (k * k - 2 * zeta * wn * k + wn * wn) / a0])
    return b, a


_UPSAMPLED: dict = {}


def _upsampled(w: np.ndarray, factor: int, axis: int) -> np.ndarray:
    """Band-limited interpolation by ``factor`` along ``axis``, remembered for the last array seen.

    A search over the mode's frequency filters the same cached stack many times.
    """
    key = (id(w), w.shape, factor, axis)
    hit = _UPSAMPLED.get("last")
    if hit is not None and hit[0] == key and hit[1] is w:
        return hit[2]
    up = signal.resample_poly(w, factor, 1, axis=axis, padtype="line")
    _UPSAMPLED["last"] = (key, w, up)
    return up


def resonance_filter(w: np.ndarray, dt_s: float, f_n_hz: float, zeta: float, axis: int = -2,
                     oversample: int = 2) -> np.ndarray:
    """Pass w through wn^2 / (s^2 + 2 zeta wn s + wn^2) along ``axis``, starting at rest on the first sample.

    The signal is interpolated ``oversample`` times (band-limited) and filtered there with a
    bilinear discretisation prewarped at the mode: at the 65 Hz ticks alone a 4 Hz mode would be
    off by about a percent, which the best-resolved channels notice.
    """
    w = np.asarray(w, float)
    ax = axis % w.ndim
    w_up = _upsampled(w, oversample, ax) if oversample > 1 else w
    b, a = _mode_coefficients(f_n_hz, zeta, dt_s / oversample)
    x0 = np.take(w_up, [0], axis=ax)
    zi = signal.lfilter_zi(b, a).reshape([-1 if i == ax else 1 for i in range(w.ndim)]) * x0
    y, _ = signal.lfilter(b, a, w_up, axis=ax, zi=zi)
    if oversample > 1:
        y = np.take(y, np.arange(0, w.shape[ax] * oversample, oversample), axis=ax)
    return y


class StructuralResonance(Effect):
    """Reading = true wrench through a 2nd-order mode wn^2 / (s^2 + 2 zeta wn s + wn^2), all channels."""

    name = "structural_resonance"
    ranges = {"f_n_hz": (0.7, 12.0), "zeta": (0.0, 1.0)}
    stage = "filter"
    physical = False
    formula = "W_read = W wn^2 / (s^2 + 2 zeta wn s + wn^2), wn = 2 pi f_n_hz"
    # a scan in frequency at moderate damping (a sharp mode is missed between coarse points), then a
    # 2-D refinement of frequency and damping from the best point
    search = (SearchParam("f_n_hz", tuple(np.round(np.arange(1.0, 8.01, 0.25), 2)), (0.5, 12.0)),
              SearchParam("zeta", (0.12,), (0.005, 1.5), log=True))
    location_params = ("f_n_hz", "zeta")

    def refusal(self, params: dict, settings) -> str | None:
        """A heavily damped mode is a delay in disguise (mount and sting modes are lightly damped)."""
        zeta, limit = params.get("zeta"), getattr(settings, "max_mode_zeta", 0.3)
        if isinstance(zeta, (int, float)) and zeta > limit:
            return (f"zeta = {zeta:.2f} > {limit:g}: a heavily damped mode is a delay (servo or circulatory lag), "
                    "not a mount mode")
        return None

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        return ccf_clause(ev, "model_force_accel", "the second derivative of the model's force")

    def filter_wrench(self, w: np.ndarray, dt_s: float, nl: dict) -> np.ndarray:  # noqa: D102
        return resonance_filter(w, dt_s, nl["f_n_hz"], nl["zeta"], axis=-2)


class LoadcellCrosstalk(Effect):
    """Reading = (I + X) @ true wrench, X off-diagonal; entries x_<to>_<from>.

    Sources the model never excites are left out, and of two (nearly) proportional sources
    only the larger is fitted (its entry then stands for both; see ``aliases``).
    """

    name = "loadcell_crosstalk"
    ranges = {"x_*": (-0.15, 0.15)}
    stage = "sensor"
    physical = False
    prunable = True
    reads_prediction = True
    formula = "W_read = (I + X) W, X off-diagonal"

    def __init__(self, pairs: list[tuple[int, int]] | None = None, aliases: dict[str, str] | None = None):
        self.pairs = pairs if pairs is not None else [(i, j) for i in range(6) for j in range(6) if i != j]
        self.aliases = dict(aliases or {})

    def options(self) -> dict:  # noqa: D102
        return {"pairs": [list(p) for p in self.pairs], "aliases": dict(self.aliases)}

    @classmethod
    def from_options(cls, options: dict | None = None) -> "LoadcellCrosstalk":  # noqa: D102
        opts = dict(options or {})
        if "pairs" in opts:
            opts["pairs"] = [tuple(p) for p in opts["pairs"]]
        return cls(**opts)

    def configure(self, sample) -> "LoadcellCrosstalk":
        """Only the entries this campaign can identify (:meth:`configured` on the base model's prediction)."""
        prediction, mask = sample()
        return self.configured(prediction, mask)

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        return ccf_clause(ev, "model_force", "the model's force in another channel")

    def notes(self, coefs: dict[str, float]) -> list[str]:  # noqa: D102
        return [f"{k} stands for {k}{self.aliases[k]} (proportional sources in this model)"
                for k in coefs if k in self.aliases]

    @staticmethod
    def entry(to: int, frm: int) -> str:
        """Parameter name of one entry."""
        return f"x_{SHORT[to]}_{SHORT[frm]}"

    def linear_names(self):  # noqa: D102
        return [self.entry(i, j) for i, j in self.pairs]

    def configured(self, prediction: np.ndarray, mask: np.ndarray, collinear: float = 0.995) -> "LoadcellCrosstalk":
        """A copy fitting only identifiable entries, judged on a sample of the predicted true wrench."""
        p = prediction[mask]  # (n, 6)
        rms = np.sqrt(np.mean(p * p, axis=0))
        scale = rms.max() if rms.max() > 0 else 1.0
        live = [j for j in range(6) if rms[j] > 1e-6 * scale]
        keep, aliases = [], {}
        for j in sorted(live, key=lambda j: -rms[j]):
            dup = None
            for k in keep:
                c = np.corrcoef(p[:, j], p[:, k])[0, 1] if rms[j] > 0 and rms[k] > 0 else 0.0
                if abs(c) >= collinear:
                    dup = k
                    break
            if dup is None:
                keep.append(j)
            else:
                ratio = float(np.dot(p[:, j], p[:, dup]) / np.dot(p[:, dup], p[:, dup]))
                for i in range(6):
                    if i not in (j, dup):
                        aliases[self.entry(i, dup)] = (aliases.get(self.entry(i, dup), "")
                                                       + f" + {ratio:.4g} {self.entry(i, j)}")
        pairs = [(i, j) for j in sorted(keep) for i in range(6) if i != j]
        return type(self)(pairs, aliases)

    def sensor_terms(self, ctx: Context, nl: dict, prediction: np.ndarray) -> Terms:  # noqa: D102
        names, cols, sup = [], [], []
        for i, j in self.pairs:
            col = np.zeros_like(prediction)
            col[..., i] = prediction[..., j]
            s = np.zeros(6, bool)
            s[i] = True
            names.append(self.entry(i, j))
            cols.append(col)
            sup.append(s)
        return Terms(names, cols, sup)


class SensorDrift(Effect):
    """Reading drifts linearly with the time since the run's first trigger edge: rate_<channel>_per_s."""

    name = "sensor_drift"
    stage = "sensor"
    physical = False
    prunable = True
    formula = "W_read += rate * t, t since the first trigger edge"

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        c = max(WRENCH_CHANNELS, key=lambda k: abs(ev.trend[k]["t"]))
        return f"the residual trends with time in the run ({c}: {ev.trend[c]['slope']:.3g}/s, t = {ev.trend[c]['t']:.1f})"

    @staticmethod
    def entry(c: int) -> str:
        """Parameter name for channel ``c``."""
        return f"rate_{WRENCH_CHANNELS[c]}_per_s"

    def linear_names(self):  # noqa: D102
        return [self.entry(c) for c in range(6)]

    def sensor_terms(self, ctx: Context, nl: dict, prediction: np.ndarray) -> Terms:  # noqa: D102
        t = np.maximum(ctx.time_s, 0.0)
        names, cols, sup = [], [], []
        for c in range(6):
            col = np.zeros(t.shape + (6,))
            col[..., c] = t
            s = np.zeros(6, bool)
            s[c] = True
            names.append(self.entry(c))
            cols.append(col)
            sup.append(s)
        return Terms(names, cols, sup)


EFFECTS = (ServoLag, TunnelBlockage, FlowUnsteadiness, StructuralResonance, LoadcellCrosstalk, SensorDrift)


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
