"""The augmented model's forward pass: commanded motion -> leg -> fluid -> structure -> load cell.

A :class:`Configuration` is an ordered set of active effects with their nonlinear parameters.
:func:`build_design` evaluates it on a batch of runs as a *linear* model in the remaining
parameters: a fixed part ``base`` (the diagnosed model on the transformed motion, plus fixed
terms) and columns whose weighted sum is added to it. Fitting, the augmented model and the
report all go through this one function, so what is fitted is exactly what is predicted.

Order of the chain (physics first, measurement last): input effects (servo lag) -> the model
and force terms -> the ingest's low-pass (matched) -> filters (structural resonance) -> sensor
terms (crosstalk from the predicted true wrench, drift).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from workbench.diagnose.effects.base import Context, Effect
from workbench.hydro.kinematics import DEFAULT_GEOMETRY


@dataclass(frozen=True)
class Lowpass:
    """The ingest's zero-phase low-pass, applied to predictions so they compare with the readings."""

    cutoff_hz: float = 6.0
    order: int = 4

    def __call__(self, x: np.ndarray, dt_s: float, axis: int) -> np.ndarray:
        """Filter ``x`` along ``axis``."""
        from workbench.signals.filters import lowpass

        return lowpass(x, 1.0 / dt_s, self.cutoff_hz, self.order, axis=axis)

    def power_gain(self, freqs_hz: np.ndarray, dt_s: float) -> np.ndarray:
        """The filter's power gain at ``freqs_hz`` (floored at 1e-12, so spectra may be divided by it)."""
        from workbench.signals.filters import frequency_response_db

        return np.maximum(10 ** (frequency_response_db(freqs_hz, 1.0 / dt_s, self.cutoff_hz, self.order) / 10), 1e-12)


@dataclass
class Active:
    """An effect in a configuration, with its nonlinear parameter values."""

    effect: Effect
    nl: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        """The effect's canonical name."""
        return self.effect.name


STAGE_ORDER = {"input": 0, "force": 1, "filter": 2, "sensor": 3}


@dataclass
class Configuration:
    """Active effects in chain order."""

    actives: list[Active] = field(default_factory=list)

    def with_effect(self, active: Active) -> "Configuration":
        """A copy with one more (or a replaced) effect."""
        rest = [a for a in self.actives if a.name != active.name]
        return Configuration(sorted(rest + [active], key=lambda a: STAGE_ORDER[a.effect.stage]))

    def without(self, name: str) -> "Configuration":
        """A copy less one effect."""
        return Configuration([a for a in self.actives if a.name != name])

    def stage(self, stage: str) -> list[Active]:
        """Active effects of one stage."""
        return [a for a in self.actives if a.effect.stage == stage]

    def names(self) -> list[str]:
        """Active effect names in chain order."""
        return [a.name for a in self.actives]

    def nl_values(self) -> dict[str, float]:
        """All nonlinear parameters as ``effect.param``."""
        return {f"{a.name}.{k}": v for a in self.actives for k, v in a.nl.items()}

    def copy(self) -> "Configuration":
        """A copy with independent parameter dicts."""
        return Configuration([Active(a.effect, dict(a.nl)) for a in self.actives])


@dataclass
class Design:
    """A configuration on one batch, linear in its remaining parameters (all arrays (B, T, 6))."""

    base: np.ndarray
    names: list[str]
    cols: list[np.ndarray]
    support: list[np.ndarray]
    local_names: list[str]
    local: list[np.ndarray]
    #: columns the model predicts with where they differ from the fitted ones, by qualified name (``Terms.predict``)
    predict_cols: dict[str, np.ndarray] = field(default_factory=dict)
    #: a known part of the reading the fits take off before fitting, which ``predict`` leaves to
    #: ``predict_cols`` (``Terms.fit_offset``); None: none
    fit_offset: np.ndarray | None = None

    #: the filter residuals are compared through in fits (an equation-error filter effect, :func:`compare_filter`)
    compare: Callable[[np.ndarray], np.ndarray] | None = None
    #: shared and per-run columns already passed through ``compare`` (by qualified name), made once per
    #: force term and filter value (:func:`_filtered`); the fits compare the others themselves
    compared: dict[str, np.ndarray] = field(default_factory=dict)
    compared_local: dict[str, np.ndarray] = field(default_factory=dict)

    def predict(self, coefs: dict[str, float], local: dict[str, np.ndarray] | None = None) -> np.ndarray:
        """Return base + sum coef * col (+ per-run columns with per-row coefficients ``local[name]`` (B,)).

        A column with a predicting form (``predict_cols``) predicts with that form.
        """
        out = self.base.copy()
        for n, c in zip(self.names, self.cols, strict=False):
            v = coefs.get(n, 0.0)
            if v:
                out += v * self.predict_cols.get(n, c)
        for n, c in zip(self.local_names, self.local, strict=False):
            if local and n in local:
                out += local[n][:, None, None] * c
        return out


def _key(actives: list[Active]) -> tuple:
    return tuple((a.name, tuple(sorted((k, round(float(v), 12)) for k, v in a.nl.items()))) for a in actives)


#: input configurations (servo lags) whose model output, kinematics and force terms stay cached per batch
_KEEP_INPUTS = 5


def _add_flow_offset(ctx: Context, flow_offset: np.ndarray | None) -> None:
    """Make ``ctx.wrench_at_flow`` carry the offset's flow sensitivity (``--reference``): + (f - 1) U dW/dU."""
    if flow_offset is None or isinstance(ctx, SurrogateContext):
        return
    plain_at = ctx.wrench_at_flow

    def at(factor: float) -> np.ndarray:
        w = plain_at(factor)
        return w if factor == 1.0 else w + (factor - 1.0) * flow_offset

    ctx.wrench_at_flow = at  # type: ignore[method-assign]


class SurrogateContext(Context):
    """A context whose model output comes from the plain motion's, for searches with an expensive model.

    * an input effect that changes the motion's timing (a servo lag) acts on the plain output
      through :meth:`~workbench.diagnose.effects.base.Effect.on_output`: ``M(lag(x)) = M(x) -
      tau dM/dt + O(tau^2)`` and so is ``lag(M(x))``, to first order for any causal
      time-invariant model;
    * one that scales the flow (tunnel blockage) gives its
      :meth:`~workbench.diagnose.effects.base.Effect.flow_factor` ``f``: the output at ``f`` comes
      from the quadratic through the plain output at factors 1 - h, 1 and 1 + h (h = 0.05; exact
      for a force quadratic in the flow, and those two runs are the flow sensitivity's anyway).

    An expensive model (a windowed LSTM: 32 steps per tick) then runs a few times for a whole
    search. The force terms still see the transformed kinematics; the final refinement and
    every held-out judgement use the model itself.
    """

    H = 0.05

    def __init__(self, rs, model, motion, geometry, plain: Context, inputs: list):
        super().__init__(rs, model, motion, geometry)
        self._plain = plain
        self._inputs = list(inputs)
        self._factor = 1.0
        for a in self._inputs:
            self._factor *= a.effect.flow_factor(a.nl)

    def _lag(self, w: np.ndarray) -> np.ndarray:
        for a in self._inputs:
            w = a.effect.on_output(w, self.dt_s, a.nl)
        return w

    def _at(self, factor: float) -> np.ndarray:
        w1 = self._plain.base
        if abs(factor - 1.0) < 1e-12:
            return w1
        h = self.H
        wp, wm = self._plain.wrench_at_flow(1 + h), self._plain.wrench_at_flow(1 - h)
        d = factor - 1.0
        return w1 + d * (wp - wm) / (2 * h) + d * d * (wp - 2 * w1 + wm) / (2 * h * h)

    @property
    def base(self) -> np.ndarray:  # type: ignore[override]
        """The plain output, at the blocked flow, through the lags (computed once per context)."""
        if "_surrogate_base" not in self.__dict__:
            self.__dict__["_surrogate_base"] = self._lag(self._at(self._factor))
        return self.__dict__["_surrogate_base"]

    def wrench_at_flow(self, factor: float) -> np.ndarray:
        """The surrogate output at a further flow factor (cached)."""
        if factor == 1.0:
            return self.base
        if factor not in self._flow_cache:
            self._flow_cache[factor] = self._lag(self._at(self._factor * factor))
        return self._flow_cache[factor]


def _context(model, rs, inputs: list[Active], geometry, cache: dict, surrogate: bool):
    """The batch's effect context under the input effects (cached), and its cache key."""
    in_key = _key(inputs)
    if surrogate:
        in_key = (("~lagged-output",),) + in_key
    ctx = cache.get(("ctx", in_key))
    recent = cache.setdefault(("recent",), [])
    if in_key in recent:
        recent.remove(in_key)
    recent.append(in_key)
    if ctx is not None:
        return ctx, in_key
    # keep the model's output for the last few input configurations: a search over a servo lag
    # visits new ones, and the step's other candidates come back to the current one (an
    # expensive model, such as a windowed LSTM, is then not run again); the plain motion's
    # output stays (lagged-output surrogates are made from it), surrogates go first
    plain_key = _key([])
    _evict(cache, recent, plain_key)
    motion = rs.motion
    for a in inputs:
        motion = a.effect.transform_motion(motion, a.nl)
    if surrogate:
        plain = cache.get(("ctx", plain_key))
        if plain is None:
            plain = Context(rs, model, rs.motion, geometry)
            _add_flow_offset(plain, getattr(rs, "flow_offset", None))
            cache[("ctx", plain_key)] = plain
            recent.insert(0, plain_key)
        ctx = SurrogateContext(rs, model, motion, geometry, plain, inputs)
    else:
        ctx = Context(rs, model, motion, geometry)
    _add_flow_offset(ctx, getattr(rs, "flow_offset", None))
    cache[("ctx", in_key)] = ctx
    return ctx, in_key


def _evict(cache: dict, recent: list, plain_key: tuple) -> None:
    """Forget the oldest input configurations beyond the last ``_KEEP_INPUTS`` (surrogates first)."""
    while len(recent) > _KEEP_INPUTS:
        spare = [k for k in recent[:-1] if k != plain_key]
        if not spare:
            break
        old = next((k for k in spare if k and k[0] == ("~lagged-output",)), spare[0])
        recent.remove(old)
        for k in [k for k in cache if k[0] in ("ctx", "term", "base", "base0", "base0s", "offset", "filtered")
                  and k[1] == old]:
            del cache[k]


def _base(ctx: Context, rs, inputs: list[Active], in_key: tuple, cache: dict, lp) -> np.ndarray:
    """The model's low-passed wrench on the transformed motion, plus a known offset (``--reference``)."""
    return _base0(ctx, rs, inputs, in_key, cache, lp).copy()


def _base0(ctx: Context, rs, inputs: list[Active], in_key: tuple, cache: dict, lp) -> np.ndarray:
    """:func:`_base`, cached (not a copy: do not change it)."""
    if ("base0", in_key) in cache:
        return cache[("base0", in_key)]
    if ("base", in_key) not in cache:
        cache[("base", in_key)] = lp(ctx.base)
    base = cache[("base", in_key)].copy()
    offset = getattr(rs, "offset", None)
    if offset is not None:
        # a known part of the true wrench the model lacks (``--reference``: the base model's misfit
        # on the reference campaign), already in the low-passed domain; filters and sensors see it,
        # and an input effect acts on it as on a model's output (a servo lag delays it, first order)
        okey = ("offset", in_key)
        if okey not in cache:
            o = offset
            for a in inputs:
                o = a.effect.on_output(o, ctx.dt_s, a.nl)
            cache[okey] = o
        base += cache[okey]
    cache[("base0", in_key)] = base
    return base


def _force_terms(a: Active, ctx: Context, in_key: tuple, cache: dict, lp) -> tuple:
    """One force effect's terms, low-passed once per motion and parameter value (the filter is linear)."""
    tkey = ("term", in_key, a.name, _key([a])[0][1])
    if tkey not in cache:
        olds = [k for k in cache if k[0] == "term" and k[2] == a.name]
        for k in olds[:-1]:
            del cache[k]
        t = a.effect.force_terms(ctx, a.nl)
        parts = [x for x in (t.fixed, *t.cols, *t.local) if x is not None]
        whole = lp(np.stack(parts)) if parts else None
        stack = list(whole) if parts else []
        fixed = stack.pop(0) if t.fixed is not None else None
        cache[tkey] = (t.names, stack[:len(t.cols)], t.support, fixed, t.local_names, stack[len(t.cols):], whole)
    return cache[tkey]


def _keep(qualified: str, only: set[str] | None) -> bool:
    return only is None or qualified in only


def build_design(model, rs, config: Configuration, coefs: dict[str, float] | None = None,
                 lowpass: Lowpass | None = None, geometry=DEFAULT_GEOMETRY,
                 only: set[str] | None = None, cache: dict | None = None, surrogate: bool = False) -> Design:
    """Evaluate ``config`` on the batch ``rs`` as base + linear columns.

    ``coefs`` (qualified names ``effect.param``) are the current values of the force-stage
    coefficients; sensor terms that read the predicted true wrench (crosstalk) use them.
    ``only`` restricts the linear columns kept (others are dropped, not folded in). ``cache``
    (a dict owned by the caller, one per batch) keeps the model and force-stage results of the
    last configurations, so a search over a filter or a sensor parameter does not redo them.
    ``surrogate``: input effects that allow it act on the model's output instead of its input
    (:class:`SurrogateContext`), for searches with an expensive model.
    The ingest's low-pass is applied after the force stage; the filter stage and the sensor
    stage are linear and time-invariant per channel, so the order does not change the result.
    """
    coefs = coefs or {}
    cache = {} if cache is None else cache
    inputs = config.stage("input")
    surrogate = surrogate and bool(inputs) and all(a.effect.surrogate_ok for a in inputs)
    ctx, in_key = _context(model, rs, inputs, geometry, cache, surrogate)

    def lp(x: np.ndarray) -> np.ndarray:
        return lowpass(x, ctx.dt_s, axis=-2) if lowpass is not None else x

    compared: dict[str, np.ndarray] = {}
    compared_local: dict[str, np.ndarray] = {}
    if config.stage("filter"):
        base, names, cols, sup, lnames, lcols = _filter_stage(config, ctx, rs, inputs, in_key, cache, lp, only,
                                                              compared, compared_local)
    else:
        base = _base(ctx, rs, inputs, in_key, cache, lp)
        base, names, cols, sup, lnames, lcols = _force_stage(config, ctx, in_key, cache, lp, only, base)
    prediction = base.copy()
    for n, c in zip(names, cols, strict=False):
        v = coefs.get(n, 0.0)
        if v:
            prediction += v * c
    d = Design(base=base, names=names, cols=cols, support=sup, local_names=lnames, local=lcols,
               compared=compared, compared_local=compared_local)
    ctx.coefs = coefs  # the current coefficients, for a sensor effect's known part (Terms.fit_offset)
    ctx.compare = compare_filter(config, ctx.dt_s)  # what the fits compare residuals through (None: as read)
    for a in config.stage("sensor"):
        _add_sensor_terms(d, a, a.effect.sensor_terms(ctx, a.nl, prediction), only)
    return d


def _force_stage(config: Configuration, ctx: Context, in_key: tuple, cache: dict, lp, only: set[str] | None,
                 base: np.ndarray) -> tuple:
    """The force effects' fixed parts added to ``base`` (in place) and their columns kept by ``only``.

    Returns ``(base, names, cols, support, local_names, local_cols)``.
    """
    names, cols, sup, lnames, lcols = [], [], [], [], []
    for a in config.stage("force"):
        t_names, t_cols, t_sup, fixed, t_lnames, t_local, _ = _force_terms(a, ctx, in_key, cache, lp)
        if fixed is not None:
            base += fixed
        for n, c, sp in zip(t_names, t_cols, t_sup, strict=False):
            if _keep(f"{a.name}.{n}", only):
                names.append(f"{a.name}.{n}")
                cols.append(c)
                sup.append(np.asarray(sp, bool))
        lnames += [f"{a.name}.{n}" for n in t_lnames]
        lcols += list(t_local)
    return base, names, cols, sup, lnames, lcols


def _filter_stage(config: Configuration, ctx: Context, rs, inputs: list[Active], in_key: tuple, cache: dict, lp,
                  only: set[str] | None, compared: dict, compared_local: dict) -> tuple:
    """:func:`_force_stage` through the filter effects, one part at a time.

    The filter stage is linear and works per column, so the base and each force effect's terms
    are filtered apart (and, in equation-error form, passed back through the fits' compare
    filter: ``compared``, ``compared_local``, filled in place) and cached per value: a search
    over a force effect with a mode claimed filters the candidate's terms only, not the whole
    design at every evaluation. Returns what :func:`_force_stage` returns.
    """
    base0 = _base0(ctx, rs, inputs, in_key, cache, lp)
    if ("base0s", in_key) not in cache:  # one array object per input configuration: a mode's interpolation reuses it
        cache[("base0s", in_key)] = base0[None]
    fbase, _ = _filtered(config, ctx, in_key, ("~base",), cache[("base0s", in_key)], cache, compare=False)
    base = fbase[0].copy()
    names, cols, sup, lnames, lcols = [], [], [], [], []
    for a in config.stage("force"):
        t_names, _, t_sup, fixed, t_lnames, _, whole = _force_terms(a, ctx, in_key, cache, lp)
        if whole is None:
            continue
        out, back = _filtered(config, ctx, in_key, (a.name, _key([a])[0][1]), whole, cache)
        k = 0
        if fixed is not None:
            base += out[0]
            k = 1
        for n, sp in zip(t_names, t_sup, strict=False):
            q = f"{a.name}.{n}"
            if _keep(q, only):
                names.append(q)
                cols.append(out[k])
                sup.append(np.asarray(sp, bool))
                if back is not None:
                    compared[q] = back[k]
            k += 1
        for n in t_lnames:
            q = f"{a.name}.{n}"
            lnames.append(q)
            lcols.append(out[k])
            if back is not None:
                compared_local[q] = back[k]
            k += 1
    return base, names, cols, sup, lnames, lcols


def _filtered(config: Configuration, ctx: Context, in_key: tuple, part: tuple, stack: np.ndarray, cache: dict,
              compare: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """One part's stack (n, B, T, 6) through the filter effects, and that through the fits' compare filter.

    Cached per input configuration, part (the base, or a force effect at a value) and filter
    values; the newest two values of a part are kept (a search over the part's value, or over
    the filter's, moves on and does not come back).
    """
    fkey = _key(config.stage("filter"))
    key = ("filtered", in_key, part, fkey)
    if key not in cache:
        olds = [k for k in cache if k[0] == "filtered" and k[1] == in_key and k[2][0] == part[0]]
        for k in olds[:-1]:
            del cache[k]
        out = stack
        for a in config.stage("filter"):
            out = a.effect.filter_wrench(out, ctx.dt_s, a.nl)
        cmp = compare_filter(config, ctx.dt_s) if compare else None
        cache[key] = (out, None if cmp is None else cmp(out))
    return cache[key]


def _add_sensor_terms(d: Design, a: Active, t, only: set[str] | None) -> None:
    """Append one sensor effect's columns to ``d`` (in place), with their predicting form where it differs.

    A per-run column that goes with an entry the fit leaves out (``Terms.local_owner``) is left out too.
    """
    for n, c, sp in zip(t.names, t.cols, t.support, strict=False):
        if _keep(f"{a.name}.{n}", only):
            d.names.append(f"{a.name}.{n}")
            d.cols.append(c)
            d.support.append(np.asarray(sp, bool))
            if t.predict and n in t.predict:
                d.predict_cols[f"{a.name}.{n}"] = t.predict[n]
    if t.fit_offset is not None:
        d.fit_offset = t.fit_offset if d.fit_offset is None else d.fit_offset + t.fit_offset
    owners = t.local_owner or [None] * len(t.local_names)
    for n, c, o in zip(t.local_names, t.local, owners, strict=False):
        if o is None or _keep(f"{a.name}.{o}", only):
            d.local_names.append(f"{a.name}.{n}")
            d.local.append(c)


def compare_filter(config: Configuration, dt_s: float) -> Callable[[np.ndarray], np.ndarray] | None:
    """The filter fits compare residuals through: the filter effects' own (equation-error form), chained; None: none."""
    out = None
    for a in config.stage("filter"):
        f = a.effect.compare_filter(a.nl, dt_s)
        if f is not None:
            out = f if out is None else (lambda x, f1=out, f2=f: f2(f1(x)))
    return out
