"""A structural mode of the mount between leg and load cell (``structural_resonance``; docs/diagnose.md)."""

from __future__ import annotations

import numpy as np
from scipy import signal

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose.effects.base import Effect, SearchParam
from workbench.diagnose.evidence import ccf_clause


def _mode_coefficients(f_n_hz: float, zeta: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear discretisation of wn^2 / (s^2 + 2 zeta wn s + wn^2), prewarped at wn (exact there)."""
    wn = 2 * np.pi * f_n_hz
    k = wn / np.tan(wn * dt_s / 2)
    a0 = k * k + 2 * zeta * wn * k + wn * wn
    b = np.array([wn * wn, 2 * wn * wn, wn * wn]) / a0
    a = np.array([1.0, (2 * wn * wn - 2 * k * k) / a0, (k * k - 2 * zeta * wn * k + wn * wn) / a0])
    return b, a


_UPSAMPLED: dict = {}
#: bytes of interpolated arrays remembered (the design's parts, each filtered at many mode values)
_UPSAMPLED_BYTES = 256 * 2**20


def _upsampled(w: np.ndarray, factor: int, axis: int) -> np.ndarray:
    """Band-limited interpolation by ``factor`` along ``axis``, remembered for the arrays seen last.

    A search over the mode's frequency filters the same cached parts of the design many times
    (the base, each force effect's terms). Entries hold their array, so an id is not reused
    while remembered; the oldest go first beyond ``_UPSAMPLED_BYTES``.
    """
    key = (id(w), w.shape, factor, axis)
    hit = _UPSAMPLED.pop(key, None)
    if hit is not None and hit[0] is w:
        _UPSAMPLED[key] = hit  # newest last
        return hit[1]
    up = signal.resample_poly(w, factor, 1, axis=axis, padtype="line")
    _UPSAMPLED[key] = (w, up)
    total = sum(v[1].nbytes for v in _UPSAMPLED.values())
    while total > _UPSAMPLED_BYTES and len(_UPSAMPLED) > 1:
        old = next(iter(_UPSAMPLED))
        total -= _UPSAMPLED.pop(old)[1].nbytes
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


def _spectrum(w: np.ndarray, dt_s: float, axis: int):
    """The spectrum of ``w`` less its end-to-end line along ``axis``, zero-padded to a fast length.

    The line through the first and last samples is taken out first (its second derivative is
    zero, its first a constant added back), so the wrap-around of the transform joins no step;
    the padding joins zeros to zeros. The readings are low-passed far below the tick rate, so
    spectral derivatives are exact there.
    """
    from scipy import fft

    ax = axis % w.ndim
    n = w.shape[ax]
    shape = [1] * w.ndim
    shape[ax] = n
    first, last = np.take(w, [0], axis=ax), np.take(w, [n - 1], axis=ax)
    line = first + (last - first) * (np.arange(n) / max(n - 1, 1)).reshape(shape)
    nf = fft.next_fast_len(n, real=True)
    spec = fft.rfft(w - line, n=nf, axis=ax)
    om = 2 * np.pi * np.fft.rfftfreq(nf, dt_s)
    shape[ax] = len(om)
    slope = (last - first) / (max(n - 1, 1) * dt_s)
    return spec, om.reshape(shape), line, slope, nf, ax


def _back(spec: np.ndarray, nf: int, n: int, ax: int) -> np.ndarray:
    from scipy import fft

    return np.take(fft.irfft(spec, n=nf, axis=ax), np.arange(n), axis=ax)


def _derivatives(w: np.ndarray, dt_s: float, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """First and second time derivatives of ``w`` along ``axis`` (spectral, :func:`_spectrum`)."""
    spec, om, _line, slope, nf, ax = _spectrum(w, dt_s, axis)
    n = w.shape[ax]
    return _back(spec * (1j * om), nf, n, ax) + slope, _back(spec * (-om * om), nf, n, ax)


def inverse_mode(w: np.ndarray, dt_s: float, f_n_hz: float, zeta: float, axis: int = -2) -> np.ndarray:
    """``w`` through the mode's inverse, 1 + 2 zeta s / wn + s^2 / wn^2, along ``axis`` (spectral derivatives)."""
    w = np.asarray(w, float)
    wn = 2 * np.pi * f_n_hz
    spec, om, line, slope, nf, ax = _spectrum(w, dt_s, axis)
    x = om / wn
    return _back(spec * (1 - x * x + 2j * zeta * x), nf, w.shape[ax], ax) + line + (2 * zeta / wn) * slope


#: how the mode is fitted (option ``form``): ``equation`` compares the reading through the inverse mode
#: with the unfiltered prediction, ``output`` the reading with the prediction through the mode
FORMS = ("equation", "output")


class StructuralResonance(Effect):
    """Reading = true wrench through a 2nd-order mode wn^2 / (s^2 + 2 zeta wn s + wn^2), all channels.

    Option ``form``: how the mode is *fitted* (the prediction is the same: the model's wrench
    through the mode). A base model's own misfit e enters the mount before the mode, so the
    reading is H (M + e): in ``output`` error form the fit compares it with H M and the residual
    H e is the misfit amplified near f_n, which pulls the mode away; in ``equation`` error form
    (default) the reading passes the inverse mode and is compared with M, and the residual is e
    itself whatever the mode (the readings' noise is amplified instead, a second order effect
    at the rig's signal levels). An inverse mode is also a notch at f_n and a slope across the
    band, which lower residual power whatever its cause, so a candidate must lower the held-out
    residual in every band and channel that holds some of it (:meth:`check`).
    """

    name = "structural_resonance"
    # a damping below 0.01 is a notch on residual power, not a structure (the equation-error search
    # runs to its bound where the misfit has power and no mode is there)
    ranges = {"f_n_hz": (0.7, 12.0), "zeta": (0.01, 1.0)}
    stage = "filter"
    physical = False
    timing = True
    formula = "W_read = W wn^2 / (s^2 + 2 zeta wn s + wn^2), wn = 2 pi f_n_hz"
    # a scan in frequency at moderate damping (a sharp mode is missed between coarse points), then a
    # 2-D refinement of frequency and damping from the best point
    search = (SearchParam("f_n_hz", tuple(np.round(np.arange(1.0, 8.01, 0.25), 2)), (0.5, 12.0)),
              SearchParam("zeta", (0.12,), (0.005, 1.5), log=True))
    location_params = ("f_n_hz", "zeta")

    #: the equation-error check (:meth:`check`): band width (Hz), the largest rise allowed in a band, and
    #: the share of a channel's residual power a band must hold to count
    band_hz = 1.0
    max_band_raise = 2.0
    min_band_share = 0.01
    #: the largest relative change of f_n the bias compensation may make (:meth:`searched`)
    max_compensation = 0.3
    compensation_passes = 4

    def __init__(self, form: str = "equation"):
        if form not in FORMS:
            from workbench.errors import ModelError

            raise ModelError(f"structural_resonance: form {form!r} is not one of {FORMS}")
        self.form = form

    def options(self) -> dict:  # noqa: D102
        return {"form": self.form}

    def __repr__(self) -> str:
        return f"StructuralResonance(form={self.form!r})"

    def refusal(self, params: dict, settings) -> str | None:
        """A heavily damped mode is a delay in disguise (mount and sting modes are lightly damped)."""
        zeta, limit = params.get("zeta"), getattr(settings, "max_mode_zeta", 0.3)
        if isinstance(zeta, (int, float)) and zeta > limit:
            return (f"zeta = {zeta:.2f} > {limit:g}: a heavily damped mode is a delay (servo or circulatory lag), "
                    "not a mount mode")
        return None

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        return ccf_clause(ev, "model_force_accel", "the second derivative of the model's force")

    def explained_frequencies(self, params: dict) -> list[float]:
        """A mount rings at its own frequency under any load (the flow's buffeting at rest included)."""
        return [params["f_n_hz"]] if params.get("f_n_hz") is not None else []

    def complete(self, params: dict, stderr: dict, problem, config, residuals: list) -> None:
        """Widen the damping's error by what the base model's timing leaves unknown (in place).

        In either form a delay ``d`` of the readings behind the prediction reads as ``2 zeta / wn``
        more (the first-order term of the inverse mode), so a misfit that follows the rate of
        the model's force moves zeta by ``wn d / 2``: 1 ms is 0.014 at 4.5 Hz. The fit leaves the
        pooled delay at zero, but how the misfit's delay scatters from run to run
        (:func:`timing_scatter`, 10-12 ms for the FED-LSTM on the rich tunnel) says how well the
        common one is known; its standard error over the runs, times ``wn / 2``, is added to
        zeta's error in quadrature. Measured on the re-measured demo copy (FED-LSTM, 4.5 Hz /
        0.08 planted): the delay +1.2 ms predicted zeta 0.097 where 0.096-0.104 was fitted.
        """
        f_n = params.get("f_n_hz")
        if f_n is None or "zeta" not in params:
            return
        delays = timing_scatter(residuals, getattr(problem, "weights", None))
        if len(delays) < 3:
            return
        sys_se = np.pi * float(f_n) * float(np.std(delays, ddof=1)) / np.sqrt(len(delays))
        stat = stderr.get("zeta", float("nan"))
        stat = 0.0 if not np.isfinite(stat) else float(stat)
        stderr["zeta"] = float(np.hypot(stat, sys_se))

    def filter_wrench(self, w: np.ndarray, dt_s: float, nl: dict) -> np.ndarray:  # noqa: D102
        return resonance_filter(w, dt_s, nl["f_n_hz"], nl["zeta"], axis=-2)

    def reading_inverse(self, nl: dict, coefs: dict, dt_s: float):
        """The inverse mode (whatever the form): the residual of the readings through the mount, undone."""
        f_n, zeta = float(nl["f_n_hz"]), float(nl["zeta"])
        return lambda x: inverse_mode(x, dt_s, f_n, zeta, axis=-2)

    def compare_filter(self, nl: dict, dt_s: float):
        """Equation-error form: residuals are compared through the inverse mode (None in output-error form)."""
        if self.form != "equation":
            return None
        f_n, zeta = float(nl["f_n_hz"]), float(nl["zeta"])

        def inverse(x: np.ndarray) -> np.ndarray:
            return inverse_mode(x, dt_s, f_n, zeta, axis=-2)

        return inverse

    def search_grams(self, problem, config, coefs: dict, names: list[str]):
        """Equation-error form: the search's sums from one design per batch (None: the plain search).

        The fit compares the reading through the inverse mode, ``y + a1 y' + a2 y''`` with
        a = (2 zeta / wn, 1 / wn^2), with the prediction through the mode and back, which is the
        prediction itself but for the mode's discretisation. So the search compares
        ``y + a1 y' + a2 y''`` with the design of ``config`` without the mode: the derivatives
        of the reading and the design are made once, and an evaluation costs one set of block
        sums instead of the whole design passed through the mode and back (0.36 s an evaluation
        against 0.02 s with a 13-effect model; docs/testing.md). Not with another filter or a
        sensor effect in ``config`` (their columns read the prediction through the mode).
        """
        if self.form != "equation" or config.stage("filter") or config.stage("sensor"):
            return None
        from workbench.diagnose import lsq

        surrogate = bool(getattr(problem, "surrogate_search", False))
        parts = []
        for rs, blocks in problem.sets("search"):
            d = problem.design(rs, config, coefs, names, surrogate=surrogate)
            if d.compare is not None or d.fit_offset is not None:
                return None
            parts.append((rs, blocks, d, d.base, *_derivatives(rs.y, rs.dt_s, -2)))

        def grams(nl: dict):
            wn = 2 * np.pi * float(nl["f_n_hz"])
            a1, a2 = 2 * float(nl["zeta"]) / wn, 1 / (wn * wn)
            out = []
            for rs, blocks, d, base, y1, y2 in parts:
                d.base = base - a1 * y1 - a2 * y2   # reading - (base - ...) = inverse mode of the reading - base
                out.append(lsq.accumulate(d, rs, blocks, names))
            gr = lsq.concat(out)
            gr.prior = problem.priors(config, gr.names)
            return gr

        return grams

    def search_reading(self, nl: dict, dt_s: float):
        """Equation-error form: the reading through the inverse mode (None in output-error form).

        The fits compare the reading through the inverse mode with the prediction through the mode
        and back, the prediction itself but for the mode's discretisation; another effect's search
        beside a claimed mode then compares that reading with the design without the mode, and an
        evaluation filters nothing.
        """
        if self.form != "equation":
            return None
        f_n, zeta = float(nl["f_n_hz"]), float(nl["zeta"])
        return lambda y: inverse_mode(y, dt_s, f_n, zeta, axis=-2)

    def searched(self, nl: dict, problem, config, coefs: dict, names: list[str]) -> dict:
        """Equation-error form: the least-squares optimum compensated for the misfit inside the reading.

        The equation error is linear in a = (2 zeta / wn, 1 / wn^2): ``M - y = a1 y' + a2 y'' - e``
        with y = H (M + e) the reading. Its regressors y', y'' carry the misfit (H e)', (H e)'', so
        least squares returns ``a - (Phi'Phi)^-1 Phi_e' e``, a damping too low by about the misfit's
        share of the reading's power near f_n (bias-compensated least squares). The misfit is
        estimated by the equation error at the compensated values and the term added back to the
        optimum (``compensation_passes`` fixed-point passes), on the search runs. A correction that moves f_n by more than ``max_compensation`` (relative) or
        leaves the plausible range is not made.
        """
        if self.form != "equation" or not {"f_n_hz", "zeta"} <= set(nl):
            return nl
        from workbench.diagnose.chain import Active

        out = dict(nl)
        wn = 2 * np.pi * nl["f_n_hz"]
        a_hat = np.array([2 * nl["zeta"] / wn, 1 / (wn * wn)])
        for _ in range(self.compensation_passes):
            gram, bias = np.zeros((2, 2)), np.zeros(2)
            for rs, _blocks in problem.sets("search"):
                d = problem.design(rs, config.with_effect(Active(self, out)), coefs, names)
                e = inverse_mode(rs.y - d.predict(coefs), rs.dt_s, out["f_n_hz"], out["zeta"])
                phi = _derivatives(rs.y, rs.dt_s, -2)
                phi_e = _derivatives(resonance_filter(e, rs.dt_s, out["f_n_hz"], out["zeta"]), rs.dt_s, -2)
                m = rs.fit
                w = problem.weights
                for i in range(2):
                    bias[i] += float((phi_e[i][m] * e[m] * w).sum())
                    for j in range(2):
                        gram[i, j] += float((phi[i][m] * phi[j][m] * w).sum())
            try:
                a = a_hat + np.linalg.solve(gram, bias)
            except np.linalg.LinAlgError:
                return nl
            if not (np.all(np.isfinite(a)) and a[0] > 0 and a[1] > 0):
                return nl
            wn_new = 1 / np.sqrt(a[1])
            new = {**out, "f_n_hz": float(wn_new / (2 * np.pi)), "zeta": float(a[0] * wn_new / 2)}
            if (abs(new["f_n_hz"] / nl["f_n_hz"] - 1) > self.max_compensation
                    or self.implausible({k: new[k] for k in ("f_n_hz", "zeta")})):
                return nl
            out = new
        return out

    #: a mode above the ingest's cutoff must lift the readings at f_n at least this much through the low-pass
    min_peak_gain = 2.0

    def hidden_by_lowpass(self, f_n_hz: float, zeta: float, lowpass) -> str | None:
        """Why a mode at ``f_n_hz``, ``zeta`` is not seen through ``lowpass`` (a ``Lowpass``; None: unfiltered)."""
        if lowpass is None or f_n_hz <= lowpass.cutoff_hz:
            return None
        amp = 1.0 / (1.0 + (f_n_hz / lowpass.cutoff_hz) ** (2 * lowpass.order))  # zero-phase Butterworth
        peak = amp / (2.0 * max(zeta, 1e-9))
        if peak >= self.min_peak_gain:
            return None
        return (f"f_n = {f_n_hz:.2f} Hz, zeta = {zeta:.2f} lies above the ingest's {lowpass.cutoff_hz:g} Hz cutoff "
                f"and its resonance lifts the filtered readings only {peak:.2f}x: its tail in band is a delay and "
                "an inertia term, not a mount mode")

    #: a mount rings: the residual before the mode must rise at f_n at least this much over its flanks,
    #: and beyond what noise alone reaches there (``ring_alpha`` over the six channels)
    min_rise = 2.0
    ring_alpha = 0.01

    def not_ringing(self, nl: dict, runs: list, lowpass) -> str | None:
        """Why the residual ``runs`` (before the mode) show no resonance at ``nl``'s f_n (None: they do).

        A mode multiplies what the mount carries by ``|H|``: ``1 / (2 zeta)`` at f_n and about a
        quarter of that ``2-4 zeta f_n`` away, so the residual before the mode, ``(H - 1) M + H e``,
        rises at f_n over its flanks (6x or more in power for a smooth spectrum; 3-12x measured on
        the battery's 4.5 Hz mode with both bases). An inverse mode is also a notch on residual power,
        so a lightly damped "mode" can gain on a residual that does not ring at all (a FED-LSTM's clean
        campaign, held-out sets covering every gait frequency: 6.7-7.0 Hz, zeta 0.015-0.02, 16 % of
        the held-out error, 1.24x its flanks; measured 28-29 Nov 2026). The rise is
        :func:`resonance_rise`; it must reach ``min_rise`` and the level that a smooth spectrum's
        noise exceeds with probability ``ring_alpha`` in any of the six channels (an F ratio of the
        band's and the flanks' bins, 4/3 degrees of freedom per Hann-tapered bin).
        """
        from scipy import stats

        f_n, zeta = float(nl.get("f_n_hz", 0.0)), float(nl.get("zeta", 1.0))
        got = resonance_rise(runs, f_n, zeta, lowpass)
        if got is None:
            return None
        rise, n_centre, n_flanks = got
        level = max(self.min_rise, float(stats.f.ppf(1 - self.ring_alpha / 6, 4 / 3 * n_centre, 4 / 3 * n_flanks)))
        if float(np.max(rise)) >= level:
            return None
        c = int(np.argmax(rise))
        return (f"the held-out residual does not ring at f_n = {f_n:.2f} Hz (zeta {zeta:.3f}): its power there is "
                f"at most {rise[c]:.2f}x its flanks' ({WRENCH_CHANNELS[c]}), a mount mode's at least {level:.2f}x")

    def check(self, cand, probe, config, fit) -> str | None:
        """Equation-error form: the inverse mode must not raise the held-out residual grossly in any band.

        A mount mode filters the whole reading, so its inverse turns the reading back into the true
        wrench and leaves the base model's own misfit e, against e + (H - 1)(M + e) without it: in
        a band where the misfit happens to cancel part of (H - 1)(M + e) the inverse raises the
        residual (1.6x measured in ty at 1-2 Hz for a right 3.8 Hz mode with the FED-LSTM), so a
        rise alone is no proof. An inverse "mode" that only attenuates residual power (a slope
        across the band, a notch) raises it where the model's force is large against its misfit,
        and the search drives it to the damping's bound (refused as implausible, zeta < 0.01).
        Checked per channel in bands of ``band_hz`` up to the cutoff, on the held-out runs, where a
        band holds at least ``min_band_share`` of the channel's residual power: more than
        ``max_band_raise`` times the residual is refused.

        In either form, a mode above the ingest's cutoff must still show its resonance through the
        low-pass: its peak gain ``1 / (2 zeta)`` times the filter's gain at ``f_n`` at least
        ``min_peak_gain`` (2). Otherwise the low-pass took the resonance out of the readings, and what
        is left in band, ``1 - (f / f_n)^2`` and a phase, is a term in the readings' second
        derivative and a delay, which a missing inertia and a servo's lag also make (with the
        FED-LSTM as base, a 25 ms command lag left a 7.0 Hz, zeta 0.12 "mode", peak gain 0.96
        through the 6 Hz low-pass, beside an 18 ms servo). A 6.5 Hz mode of zeta 0.05 shows 3.4.
        """
        nl = cand.active.nl
        why = self.hidden_by_lowpass(float(nl.get("f_n_hz", 0.0)), float(nl.get("zeta", 1.0)), probe.problem.lowpass)
        if why:
            return why
        why = self.not_ringing(nl, [r for r in probe.residuals(config, fit) if r.heldout], probe.problem.lowpass)
        if why:
            return why
        if self.form != "equation":
            return None
        edges = np.arange(0.0, probe.cutoff + self.band_hz / 2, self.band_hz)
        before = _band_power([r for r in probe.residuals(config, fit) if r.heldout], edges, None)
        after = _band_power([r for r in probe.run_residuals(cand.config, cand.fit) if r.heldout], edges,
                            (float(nl["f_n_hz"]), float(nl["zeta"])))
        if before is None or after is None:
            return None
        counted = before >= self.min_band_share * before.sum(axis=0, keepdims=True)
        ratio = np.where(counted, after / np.maximum(before, 1e-300), 0.0)
        b, c = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
        if ratio[b, c] > self.max_band_raise:
            return (f"the inverse mode raises the held-out residual of {WRENCH_CHANNELS[c]} at "
                    f"{edges[b]:g}-{edges[b + 1]:g} Hz {ratio[b, c]:.2f}x")
        return None


def timing_scatter(runs: list, weights: np.ndarray | None = None) -> np.ndarray:
    """Per run, the delay (s) of the readings behind the prediction that best explains its residual.

    ``d_r = -<P', r> / <P', P'>`` over the run's analysed ticks, channels weighted by ``weights``
    (``P`` the prediction, ``r`` the residual; ``P(t - d) = P - d P'`` to first order). Runs whose
    prediction does not move are left out.
    """
    w = np.ones(6) if weights is None else np.asarray(weights, float)
    out = []
    for r in runs:
        m = np.asarray(r.fit, bool)
        if m.sum() < 16:
            continue
        rate = np.gradient(np.asarray(r.predicted, float), r.dt_s, axis=0)[m]
        res = np.asarray(r.resid, float)[m]
        den = float((rate * rate * w).sum())
        if den > 0:
            out.append(-float((rate * res * w).sum()) / den)
    return np.asarray(out)


def resonance_rise(runs: list, f_n_hz: float, zeta: float, lowpass=None) -> tuple[np.ndarray, int, int] | None:
    """How much the runs' residual power rises at ``f_n_hz`` over its flanks (None: no run resolves them).

    Returns the rise per channel (6,), the band's bins and the flanks' bins.

    Power density (Hann-tapered, summed over runs, divided by the ingest's low-pass power gain
    ``lowpass`` so a mode near the cutoff is not judged by the filter's slope) in the band
    ``|f - f_n| <= w``, ``w = max(zeta f_n, 1.5 df)`` (the resonance's half-power half-width, at
    least a bin and a half), over the geometric mean of the densities at ``2w-4w`` below and above
    (a power-law background cancels).
    """
    acc, counts = np.zeros((3, 6)), np.zeros(3)   # the band, the lower and the upper flank
    for r in runs:
        x = r.resid[r.fit]
        if len(x) < 16:
            continue
        x = x - x.mean(axis=0)
        taper = np.hanning(len(x))
        spec = np.abs(np.fft.rfft(x * taper[:, None], axis=0)) ** 2
        freq = np.fft.rfftfreq(len(x), r.dt_s)
        if lowpass is not None:
            spec = spec / lowpass.power_gain(freq, r.dt_s)[:, None]
        w = max(zeta * f_n_hz, 1.5 * freq[1])
        d = freq - f_n_hz
        sels = (np.abs(d) <= w, (d <= -2 * w) & (d >= -4 * w) & (freq > 0), (d >= 2 * w) & (d <= 4 * w))
        if not all(sel.any() for sel in sels):
            continue
        for i, sel in enumerate(sels):
            acc[i] += spec[sel].sum(axis=0)
            counts[i] += int(sel.sum())
    if not counts.all():
        return None
    dens = acc / counts[:, None]
    return dens[0] / np.maximum(np.sqrt(dens[1] * dens[2]), 1e-300), int(counts[0]), int(counts[1] + counts[2])


def _band_power(runs: list, edges: np.ndarray, mode: tuple[float, float] | None) -> np.ndarray | None:
    """Residual power of the runs' analysed ticks per band (rows) and channel, the residual through the inverse mode."""
    out = np.zeros((len(edges) - 1, 6))
    for r in runs:
        x = r.resid
        if mode is not None:
            x = inverse_mode(x, r.dt_s, mode[0], mode[1], axis=0)
        x = x[r.fit]
        if len(x) < 8:
            continue
        spec = np.abs(np.fft.rfft(x - x.mean(axis=0), axis=0)) ** 2
        freq = np.fft.rfftfreq(len(x), r.dt_s)
        band = np.digitize(freq, edges) - 1
        ok = (band >= 0) & (band < len(edges) - 1)
        np.add.at(out, band[ok], spec[ok])
    return out if out.any() else None


LIBRARY_RANK = 4  # place in the library's order (workbench.diagnose.library._in_tree)

EFFECTS = (StructuralResonance,)
