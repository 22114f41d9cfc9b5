"""Close the loop: residual -> evidence -> effects -> augmented model -> error before and after.

:func:`diagnose` is the one domain function behind ``workbench diagnose``: it takes a processed
tunnel frame and a leg force model, and returns a :class:`Diagnosis` (what ``diagnosis.json``,
the report and the augmented model are written from). No files are touched here.
"""

from __future__ import annotations

import contextlib
import sys
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose import evidence as ev_mod
from workbench.diagnose import lsq
from workbench.diagnose.augmented import AugmentedLegModel
from workbench.diagnose.chain import Active, Configuration, Design, Lowpass
from workbench.diagnose.data import DataSettings, prepare
from workbench.diagnose.evidence import Evidence, EvidenceSettings, analyse
from workbench.diagnose.library import EffectLibrary, default_library
from workbench.diagnose.problem import FitSettings, Problem, run_residuals
from workbench.diagnose.selection import SelectionSettings, StepwiseSelection, judge

CHANNELS = list(WRENCH_CHANNELS)


@dataclass(frozen=True)
class LibrarySettings:
    """Which effects are candidates and their fixed options (section ``library``)."""

    #: effect names (empty: the whole documented library)
    effects: tuple[str, ...] = ()
    #: lateral offset of thigh and calf from the hip axis (m) and Gauss points per link
    link_x_m: float = 0.01
    link_quadrature: int = 4
    #: drag coefficient of the force that passes the circulatory lag (null: the EF's own C_R)
    circulatory_c_r: float | None = None
    #: constructor options per effect, ``{effect: {option: value}}`` (an effect's own knobs, e.g.
    #: ``wagner_lag: {time_scale: 1.2}``); they win over the shared keys above
    options: dict = field(default_factory=dict)


@dataclass(frozen=True)
class ReportSettings:
    """What counts as unexplained, and report details (section ``report``)."""

    #: a gait-locked misfit is reported when, beyond noise, it holds at least this share of a channel's residual
    locked_min_share: float = 0.2
    #: a channel's effect contribution is listed when it removes at least this share of its error
    channel_min_gain: float = 0.02
    example_runs: int = 3


@dataclass(frozen=True)
class DiagnoseSettings:
    """Every knob of the diagnosis (``pipelines/diagnose.yaml``)."""

    data: DataSettings = field(default_factory=DataSettings)
    fit: FitSettings = field(default_factory=FitSettings)
    selection: SelectionSettings = field(default_factory=SelectionSettings)
    evidence: EvidenceSettings = field(default_factory=EvidenceSettings)
    library: LibrarySettings = field(default_factory=LibrarySettings)
    report: ReportSettings = field(default_factory=ReportSettings)
    #: match the ingest's zero-phase low-pass on the predictions (null: from the processed file)
    lowpass_cutoff_hz: float | None = None
    lowpass_order: int | None = None
    match_lowpass: bool = True

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | None, path: str | None = None) -> "DiagnoseSettings":
        """Build from the YAML section of file ``path`` (workbench.params).

        Unknown keys and wrong types are a ParamsError naming the key path (``diagnose.fit.surrogate_serch``).
        """
        from workbench.params import build

        values = dict(values or {})
        # the trajectory level reads its own section (workbench.diagnose.trajectory.TrajectorySettings)
        values.pop("trajectory", None)
        return build(cls, values, key="diagnose", path=path)


@dataclass
class EffectReport:
    """A claimed effect: canonical parameters with intervals, evidence and held-out error reduction."""

    name: str
    channels: list[str]
    params: dict[str, float]
    stderr: dict[str, float]
    evidence: str
    heldout_mse_reduction: float
    heldout_mse_reduction_by_channel: dict[str, float]
    test: dict
    alternatives: list[str]
    notes: list[str] = field(default_factory=list)
    #: effects the data cannot tell apart from this one (data contract section 4)
    ambiguous_with: list[str] = field(default_factory=list)

    def to_json(self) -> dict:
        """Contract entry plus intervals and test statistics."""
        ci = {k: [_num(self.params[k] - 1.96 * v), _num(self.params[k] + 1.96 * v)]
              for k, v in self.stderr.items() if k in self.params and _isnum(self.params[k]) and np.isfinite(v)}
        return {"name": self.name, "channels": self.channels,
                "params": {k: _num(v) for k, v in self.params.items()},
                "evidence": self.evidence, "heldout_mse_reduction": _num(self.heldout_mse_reduction),
                "stderr": {k: _num(v) for k, v in self.stderr.items()}, "ci95": ci,
                "heldout_mse_reduction_by_channel": {k: _num(v) for k, v in
                                                     self.heldout_mse_reduction_by_channel.items()},
                "test": {k: _num(v) for k, v in self.test.items()}, "alternatives": self.alternatives,
                "notes": self.notes, **({"ambiguous_with": self.ambiguous_with} if self.ambiguous_with else {})}


@dataclass
class Unexplained:
    """Residual structure no library effect explains."""

    kind: str
    channels: list[str]
    evidence: str
    frequency_hz: float | None = None

    def to_json(self) -> dict:
        """Contract entry."""
        out = {"kind": self.kind, "channels": self.channels}
        if self.frequency_hz is not None:
            out["frequency_hz"] = _num(self.frequency_hz)
        out["evidence"] = self.evidence
        return out


@dataclass
class Diagnosis:
    """The outcome of one diagnosis (domain object; the CLI writes it out)."""

    model: str
    campaign_id: str
    mse_before: dict[str, float]
    mse_after: dict[str, float]
    effects: list[EffectReport]
    unexplained: list[Unexplained]
    augmented: AugmentedLegModel
    evidence_before: Evidence
    evidence_after: Evidence
    residuals_before: list
    residuals_after: list
    steps: list
    final_table: list[dict]
    heldout_runs: list[str]
    train_runs: list[str]
    settings: DiagnoseSettings
    runtime_s: float = 0.0
    profiles: dict = field(default_factory=dict)
    #: what was learned on the reference campaign (``--reference``), None without one
    reference: dict | None = None

    def to_json(self) -> dict:
        """``diagnosis.json`` (data contract section 4) with extra keys."""
        rel = {c: _num(1 - self.mse_after[c] / self.mse_before[c]) if self.mse_before[c] > 0 else 0.0
               for c in CHANNELS}
        return {
            "model": self.model,
            "channels": CHANNELS,
            "mse_before": {c: _num(self.mse_before[c]) for c in CHANNELS},
            "mse_after": {c: _num(self.mse_after[c]) for c in CHANNELS},
            "effects": [e.to_json() for e in self.effects],
            "unexplained": [u.to_json() for u in self.unexplained],
            "campaign": self.campaign_id,
            "heldout_runs": self.heldout_runs,
            "n_train_runs": len(self.train_runs),
            "mse_relative_reduction": rel,
            "evidence_before": self.evidence_before.summary(),
            "evidence_after": self.evidence_after.summary(),
            "selection": [{"step": i + 1, "candidates": s.table} for i, s in enumerate(self.steps)]
            + [{"step": len(self.steps) + 1, "candidates": self.final_table, "stopped": True}],
            "runtime_s": round(self.runtime_s, 2),
            **({"reference": self.reference} if self.reference else {}),
        }


def _isnum(v) -> bool:
    return isinstance(v, (int, float, np.floating)) and not isinstance(v, bool)


def _num(v):
    if v is None or not _isnum(v):
        return v
    v = float(v)
    return float(f"{v:.6g}") if np.isfinite(v) else None


# --------------------------------------------------------------------------- helpers
def _heldout_mse(runs) -> dict[str, float]:
    e = np.concatenate([r.resid[r.fit] for r in runs if r.heldout])
    return {c: float((e[:, i] ** 2).mean()) for i, c in enumerate(CHANNELS)}


def _nl_stderr(problem: Problem, config: Configuration, fit: lsq.Fit, names: list[str]) -> dict[str, float]:
    """Standard errors of nonlinear parameters: Gauss-Newton columns d(prediction)/d(param) in the sandwich fit."""
    out: dict[str, float] = {}
    coefs = fit.coefs()
    for a in config.actives:
        for p, v in a.nl.items():
            h = max(abs(v) * 0.02, 1e-4)
            parts = []
            for rs, blocks in problem.sets("all"):
                preds = []
                for sign in (1, -1):
                    cfg = config.with_effect(Active(a.effect, {**a.nl, p: v + sign * h}))
                    d = problem.design(rs, cfg, coefs, names)
                    preds.append(d.predict(coefs, _local_rows(fit, d, rs)))
                d0 = problem.design(rs, config, coefs, names)
                jac = (preds[0] - preds[1]) / (2 * h)
                dj = Design(d0.base, d0.names + ["__jac__"], d0.cols + [jac], d0.support + [np.ones(6, bool)],
                            d0.local_names, d0.local)
                parts.append(lsq.accumulate(dj, rs, blocks, names + ["__jac__"]))
            gr = lsq.concat(parts)
            # the Jacobian's coefficient is the parameter's Gauss-Newton correction; its sandwich
            # error, with the linear terms refitted beside it, is the parameter's profiled error
            f = lsq.fit(gr, problem.weights, problem.settings.hac_lags)
            out[f"{a.name}.{p}"] = float(np.sqrt(max(f.cov[-1, -1], 0.0)))
    return out


def _local_rows(fit: lsq.Fit, d: Design, rs) -> dict[str, np.ndarray] | None:
    if not d.local_names or not fit.local:
        return None
    m = len(d.local_names)
    vals = np.array([fit.local.get(int(i), np.zeros(m)) for i in rs.index])
    return {n: vals[:, j] for j, n in enumerate(d.local_names)}


def _local_table(fit: lsq.Fit, grams: lsq.Grams, campaign, effect: str) -> dict[str, tuple] | None:
    """One effect's per-run columns: (values, information, flow speed) over runs, by local name (None: none)."""
    if not grams.local_names or not fit.local:
        return None
    runs = sorted(fit.local)
    out = {}
    for j, n in enumerate(grams.local_names):
        owner, local = n.split(".", 1)
        if owner != effect:
            continue
        vals = np.array([fit.local[r][j] for r in runs])
        info = np.array([fit.local_info[r][j] for r in runs])
        flows = np.array([campaign.runs[r].flow_speed_mps for r in runs])
        out[local] = (vals, info, flows)
    return out or None


class Probe:
    """The loop's view of the residuals, for the hooks through which effects propose and check themselves.

    ``problem``: the fitting problem; ``settings``: the :class:`DiagnoseSettings`; ``cutoff``: the
    highest frequency examined; ``residuals(config, fit)``: every run's residual under a
    configuration (the base model's when it is empty; the last one is remembered);
    ``peaks_of(config, fit)``: its narrowband lines.
    """

    def __init__(self, problem: Problem, settings: "DiagnoseSettings", cutoff: float, res_before: list,
                 ev_before: Evidence):
        self.problem = problem
        self.settings = settings
        self.cutoff = cutoff
        self.res_before = res_before
        self.ev_before = ev_before
        self._cache: dict[int, list] = {}

    def run_residuals(self, config: Configuration, fit: lsq.Fit) -> list:
        """Every run's residual under ``config`` fitted by ``fit`` (computed afresh)."""
        return run_residuals(self.problem, config, fit)

    def residuals(self, config: Configuration, fit: lsq.Fit) -> list:
        """Every run's residual under ``config`` (the base model's when empty; the last one cached)."""
        if not config.actives:
            return self.res_before
        key = id(fit)
        if key not in self._cache:
            self._cache.clear()
            self._cache[key] = run_residuals(self.problem, config, fit)
        return self._cache[key]

    def peaks_of(self, config: Configuration, fit: lsq.Fit) -> list:
        """The residual's narrowband lines under ``config``."""
        if not config.actives:
            return self.ev_before.peaks
        return ev_mod.peaks(self.residuals(config, fit), self.settings.evidence, self.cutoff)


# ------------------------------------------------------------------------------ loop
def one_blas_thread():
    """Run small linear algebra on one BLAS thread.

    The diagnosis does thousands of small matrix products; a multi-threaded BLAS on a shared
    two-core machine spends up to a thousand times longer synchronising its threads than
    computing them (measured: 70 ms instead of 0.05 ms for a 1500 x 25 Gram matrix).
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - an optional speed-up
        import contextlib

        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


@contextlib.contextmanager
def torch_threads_for_load():
    """Torch's intra-op threads set to the cores idle now (``workbench.threads`` ``auto``), restored after.

    Only when torch is already loaded (a learned base model such as the FED-LSTM); an EF
    diagnosis never imports it. Two OpenMP threads on a two-core machine that other jobs share
    wait on each other whenever one is descheduled: profiled on the demo campaign under a load
    average of 13, ``torch.lstm`` took 160 s of wall time for a run whose whole process used
    84 s of CPU. One thread per idle core keeps the model runs compute-bound.
    """
    torch = sys.modules.get("torch")
    if torch is None:
        yield None
        return
    from workbench.threads import resolve

    old = torch.get_num_threads()
    n = resolve("auto")
    torch.set_num_threads(n)
    try:
        yield n
    finally:
        torch.set_num_threads(old)


def _chunks_for(model, data: DataSettings) -> DataSettings:
    """Smaller batches for an expensive model: every padded tick costs a model run (a 32-step LSTM)."""
    import dataclasses

    from workbench.hydro.motion import LegMotion

    n = 256
    z = np.zeros((2, n))
    probe = LegMotion(1 / 65, z - 40.0, z + 40.0, z, z, z + 0.1, z, z)
    t0 = time.perf_counter()
    try:
        model.wrench(probe)
    except Exception:  # noqa: BLE001 - a model that cannot run a probe is diagnosed as configured
        return data
    us = 1e6 * (time.perf_counter() - t0) / (2 * n)
    if us > FitSettings().expensive_us_per_tick and data.chunk_runs > 12:
        return dataclasses.replace(data, chunk_runs=12)
    return data


def diagnose(frame, model, model_spec: str = "model", settings: DiagnoseSettings | None = None,
             library: EffectLibrary | None = None, selection: StepwiseSelection | None = None,
             lowpass: Lowpass | None = None, progress: Callable[[str], None] | None = None,
             source: str = "processed frame", reference=None, reference_source: str = "reference") -> Diagnosis:
    """Diagnose ``model`` on a processed tunnel frame (contract section 3).

    ``reference``: the processed frame of a reference campaign on the same rig. The base
    model's stroke-locked misfit there (``workbench.diagnose.reference``) is taken out of this
    campaign's readings first, so that only what changed since the reference is diagnosed.
    """
    with one_blas_thread(), torch_threads_for_load():
        return _diagnose(frame, model, model_spec, settings, library, selection, lowpass, progress, source,
                         reference, reference_source)


def _diagnose(frame, model, model_spec, settings, library, selection, lowpass, progress, source,
              reference=None, reference_source="reference") -> Diagnosis:
    t_start = time.perf_counter()
    s = settings or DiagnoseSettings()
    say = progress or (lambda msg: None)
    campaign = prepare(frame, _chunks_for(model, s.data), source)
    if lowpass is None and s.match_lowpass:
        lowpass = Lowpass(s.lowpass_cutoff_hz or 6.0, s.lowpass_order or 4)
    cutoff = lowpass.cutoff_hz if lowpass else s.evidence.fmax_hz
    if library is None:
        c_r = s.library.circulatory_c_r
        if c_r is None:
            c_r = float(getattr(getattr(model, "params", None), "c_r", 0.7))
        library = default_library(list(s.library.effects) or None, s.library.link_x_m, s.library.link_quadrature, c_r,
                                  options=s.library.options)
    selection = selection or StepwiseSelection(s.selection)
    ref_summary = None
    if reference is not None:
        from workbench.diagnose.reference import learn_reference

        say("learning the base model's stroke-locked misfit on the reference campaign")
        corr = learn_reference(reference, model, lowpass, s.fit, s.data, cutoff, source=reference_source)
        campaign = corr.apply(campaign)
        ref_summary = corr.summary()
        say(f"reference {corr.campaign_id}: {corr.matched} runs matched exactly, {corr.nearest} by nearest "
            "parameters; diagnosing what changed")
    say(f"{len(campaign.runs)} runs ({int(campaign.heldout.sum())} held out); fitting the model's residual")
    problem = Problem(campaign, model, lowpass, s.fit)
    base_fit = problem.fit(Configuration(), names=[])
    res_before = run_residuals(problem, Configuration(), base_fit)
    ev_before = analyse(res_before, s.evidence, cutoff, model_force=[r.predicted for r in res_before])
    probe = Probe(problem, s, cutoff, res_before, ev_before)

    def peaks_of(effect, config: Configuration, fit: lsq.Fit):
        return effect.proposals(probe, config, fit)

    def plausible(cand, config: Configuration, fit: lsq.Fit):
        why = cand.effect.check(cand, probe, config, fit)
        return (False, why) if why else (True, "")

    say("selecting effects (held-out runs judge each candidate)")
    result = selection.select(problem, library, peaks_of=peaks_of, plausible=plausible, progress=None)
    say(f"{len(result.config.actives)} effect(s) claimed; errors and intervals")
    mse_before = _heldout_mse(res_before)
    result, effects = _enforce_claims(problem, result, base_fit, mse_before, ev_before, s, say)
    final, config = result.fit, result.config
    res_after = run_residuals(problem, config, final)
    ev_after = analyse(res_after, s.evidence, cutoff, model_force=[r.predicted for r in res_after])
    mse_after = _heldout_mse(res_after)
    claimed = {a.name: a.effect for a in config.actives}
    for e in effects:
        claimed[e.name].complete(e.params, e.stderr, problem, config, res_after)
    unexplained = _unexplained(ev_after, effects, claimed, s)
    coefs = final.coefs()
    local: dict[str, dict[str, float]] = {}
    for j, n in enumerate(final.grams.local_names):
        local[n] = {campaign.runs[r].run_id: float(v[j]) for r, v in final.local.items()}
    augmented = AugmentedLegModel(model, model_spec, config.copy(), coefs, lowpass, local,
                                  name=f"{getattr(model, 'name', 'model')}+diagnosed",
                                  info={"campaign": campaign.campaign_id, "effects": [e.name for e in effects]})
    return Diagnosis(
        model=model_spec, campaign_id=campaign.campaign_id, mse_before=mse_before, mse_after=mse_after,
        effects=effects, unexplained=unexplained, augmented=augmented, evidence_before=ev_before,
        evidence_after=ev_after, residuals_before=res_before, residuals_after=res_after, steps=result.steps,
        final_table=result.last_table, heldout_runs=campaign.run_ids(True), train_runs=campaign.run_ids(False),
        settings=s, runtime_s=time.perf_counter() - t_start,
        profiles={st.candidate.effect.name: st.candidate.profile for st in result.steps if st.candidate.profile},
        reference=ref_summary)


def _effect_reports(problem: Problem, result, base_fit: lsq.Fit, mse_before: dict, ev_before: Evidence,
                    s: DiagnoseSettings) -> list[EffectReport]:
    """Canonical parameters, intervals, sequential held-out reductions and evidence of each claimed effect."""
    final = result.fit
    config, names = result.config, result.names
    nl_se = _nl_stderr(problem, config, final, names) if any(a.nl for a in config.actives) else {}
    cov_names = list(final.names)
    cov = {(a, b): float(final.cov[i, j]) for i, a in enumerate(cov_names) for j, b in enumerate(cov_names)}
    cov.update({(k, k): v * v for k, v in nl_se.items()})
    order = [st.candidate.effect.name for st in result.steps]
    coefs = final.coefs()
    prefix_fits: dict[frozenset, lsq.Fit] = {}

    def prefix_fit(members) -> lsq.Fit:
        key = frozenset(members)
        if key not in prefix_fits:
            part = Configuration([a for a in config.actives if a.name in key])
            prefix_fits[key] = problem.fit(part, coefs, [n for n in names if n.split(".", 1)[0] in key])
        return prefix_fits[key]

    def heldout_mse(f: lsq.Fit) -> np.ndarray:
        h = f.grams.heldout
        return f.sse_block_c[h].sum(axis=0) / max(f.grams.n[h].sum(), 1)

    # an effect that only helps once a later one is in (a collinear partner) would show a negative
    # share in selection order: it moves one place later until every share is positive
    for _ in range(len(order) ** 2):
        prev_m = heldout_mse(base_fit)
        moved = False
        for i in range(len(order) - 1):
            m = heldout_mse(prefix_fit(order[: i + 1]))
            if np.mean((prev_m - m) / np.maximum(prev_m, 1e-300)) <= 0:
                order[i], order[i + 1] = order[i + 1], order[i]
                moved = True
                break
            prev_m = m
        if not moved:
            break
    # sequential held-out MSE with the final nonlinear values: effect i's share of the error removed
    prev = base_fit
    hb = base_fit.grams.heldout
    m0 = base_fit.sse_block_c[hb].sum(axis=0) / max(base_fit.grams.n[hb].sum(), 1)
    reports = []
    for i, name in enumerate(order):
        f = prefix_fit(order[: i + 1])
        h = f.grams.heldout
        n_h = max(f.grams.n[h].sum(), 1)
        mp = prev.sse_block_c[h].sum(axis=0) / n_h
        ma = f.sse_block_c[h].sum(axis=0) / n_h
        test, _ = judge(prev, f, f.grams, problem.settings.hac_lags)
        by_ch = np.where(m0 > 0, (mp - ma) / np.maximum(m0, 1e-300), 0.0)
        step_rel = np.where(mp > 0, (mp - ma) / np.maximum(mp, 1e-300), 0.0)
        chans = [c for c, g in zip(CHANNELS, step_rel, strict=False) if g >= s.report.channel_min_gain]
        act = next(a for a in config.actives if a.name == name)
        eff_coefs = {k.split(".", 1)[1]: v for k, v in coefs.items() if k.split(".", 1)[0] == name}
        eff_cov = {(a.split(".", 1)[1], b.split(".", 1)[1]): v for (a, b), v in cov.items()
                   if a.split(".", 1)[0] == name and b.split(".", 1)[0] == name}
        params, se = act.effect.canonical_params(eff_coefs, dict(act.nl), eff_cov,
                                                 _local_table(final, final.grams, problem.campaign, name))
        step = next(st for st in result.steps if st.candidate.effect.name == name)
        best_c = CHANNELS[int(np.argmax(step_rel))]
        reduction = float(by_ch.mean())
        hint = act.effect.hint(ev_before, params)
        alt = f"; {', '.join(step.alternatives)} explained nearly as much" if step.alternatives else ""
        sentence = (f"{hint + '; ' if hint else ''}adding {name} removes {step_rel.max():.0%} of the held-out "
                    f"{best_c} error (held-out t = {test['t']:.1f} over {test['n_blocks']} blocks){alt}.")
        notes = list(act.effect.notes(eff_coefs))
        amb = [n for n in step.ambiguous_with if n != name]
        if amb:
            notes.append(f"the held-out data cannot tell {name} from {', '.join(amb)} (the winner's held-out "
                         "gain over each is not significant): the attribution is ambiguous")
        reports.append(EffectReport(name, chans, params, se, sentence, reduction,
                                    {c: float(v) for c, v in zip(CHANNELS, by_ch, strict=False)}, test,
                                    step.alternatives, notes, amb))
        prev = f
    return reports


def _claim_faults(rep: EffectReport, effect, s: DiagnoseSettings) -> str | None:
    """Why a claimed effect may not stand once its final intervals are known (None when it may)."""
    from workbench.diagnose.selection import magnitude_intervals

    spans = magnitude_intervals(rep.params, rep.stderr, s.selection.interval_z, effect.location_params)
    if spans and all(spans.values()):
        return f"every magnitude parameter's 95 % interval spans zero ({', '.join(spans)})"
    return effect.refusal(rep.params, s.selection)


def _enforce_claims(problem: Problem, result, base_fit: lsq.Fit, mse_before: dict, ev_before: Evidence,
                    s: DiagnoseSettings, say: Callable[[str], None]):
    """No claim without evidence: drop claimed effects whose final intervals span zero (weakest first).

    Selection already refuses linear effects whose interval spans zero; searched parameters
    (a lag's time constant, a mode's damping after the final joint refinement) get their
    profiled errors only here. Each drop refits the remaining effects and recomputes every report.
    """
    while True:
        effects = _effect_reports(problem, result, base_fit, mse_before, ev_before, s)
        claimed = {a.name: a.effect for a in result.config.actives}
        faults = {e.name: _claim_faults(e, claimed[e.name], s) for e in effects}
        faults = {k: v for k, v in faults.items() if v}
        if not faults:
            return result, effects
        worst = min((e for e in effects if e.name in faults), key=lambda e: e.heldout_mse_reduction)
        say(f"dropped {worst.name}: {faults[worst.name]}")
        config = result.config.without(worst.name)
        names = [n for n in result.names if n.split(".", 1)[0] != worst.name]
        fit = problem.fit(config, result.fit.coefs(), names)
        steps = [st for st in result.steps if st.candidate.effect.name != worst.name]
        table = list(result.last_table) + [{"effect": worst.name, "label": worst.name, "t": worst.test.get("t", 0.0),
                                            "p": worst.test.get("p", 1.0), "llr": worst.test.get("llr", 0.0),
                                            "max_gain": max(worst.heldout_mse_reduction_by_channel.values(),
                                                            default=0.0), "ok": False,
                                            "note": f"dropped after the final fit: {faults[worst.name]}"}]
        result = type(result)(config, names, fit, steps, table)


def _unexplained(ev: Evidence, effects: list[EffectReport], claimed: dict, s: DiagnoseSettings) -> list[Unexplained]:
    """Residual structure left after the claimed effects: lines, stroke-locked misfit, trends."""
    out: list[Unexplained] = []
    lines = [f for e in effects for f in claimed[e.name].explained_frequencies(e.params)]
    for p in ev.peaks:
        if any(abs(p.frequency_hz - f) < 0.1 for f in lines):
            continue
        best = max(p.ratio, key=p.ratio.get)
        out.append(Unexplained("narrowband", sorted(p.channels, key=CHANNELS.index),
                               f"a line at {p.frequency_hz:.2f} Hz stands {p.ratio[best]:.0f}x above the residual "
                               f"floor in {best}, in runs of every gait frequency (locked to nothing the rig does), "
                               f"and no library effect removes it.", p.frequency_hz))
    r = s.report
    # the share of the residual that repeats every stroke beyond what noise puts at the harmonics
    excess = {c: ev.locked_share[c] * max(0.0, 1 - 1 / max(ev.locked_ratio[c], 1e-9)) for c in CHANNELS}
    locked = [c for c in CHANNELS if ev.locked_p[c] < s.evidence.locked_alpha
              and ev.locked_ratio[c] >= s.evidence.locked_ratio and excess[c] >= r.locked_min_share]
    if locked:
        worst = max(locked, key=lambda c: ev.locked_share[c])
        out.append(Unexplained("gait_locked", locked,
                               f"{ev.locked_share[worst]:.0%} of the {worst} residual repeats every stroke "
                               f"({ev.locked_ratio[worst]:.1f}x the power noise would put at the gait harmonics): "
                               "a misfit of the force physics no library effect removes."))
    trend = [c for c in CHANNELS if ev.trend[c]["p"] < s.evidence.trend_alpha
             and ev.trend[c]["share"] >= s.evidence.trend_min_share]
    if trend:
        worst = max(trend, key=lambda c: abs(ev.trend[c]["t"]))
        out.append(Unexplained("trend", trend,
                               f"the {worst} residual drifts by {ev.trend[worst]['slope']:.3g} per second within "
                               f"runs (t = {ev.trend[worst]['t']:.1f}) beyond what the claimed effects removed."))
    return out
