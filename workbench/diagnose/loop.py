"""Close the loop: residual -> evidence -> effects -> augmented model -> error before and after.

:func:`diagnose` is the one domain function behind ``workbench diagnose``: it takes a processed
tunnel frame and a leg force model, and returns a :class:`Diagnosis` (what ``diagnosis.json``,
the report and the augmented model are written from). No files are touched here.

The loop's parts live beside it: ``loop_settings`` (the knobs), ``loop_results`` (what it
returns), ``loop_claims`` (effect reports, intervals, dropped claims, the unexplained) and
``loop_threads`` (BLAS/torch threads, batch size). Every name they define is re-exported here.
"""

from __future__ import annotations

import time
from typing import Callable

from workbench.contract.columns import WRENCH_CHANNELS  # noqa: F401 - importable from here as before the split
from workbench.diagnose import evidence as ev_mod  # noqa: F401 - importable from here as before the split
from workbench.diagnose import lsq
from workbench.diagnose.augmented import AugmentedLegModel
from workbench.diagnose.chain import Active, Configuration, Design, Lowpass  # noqa: F401
from workbench.diagnose.data import DataSettings, prepare  # noqa: F401
from workbench.diagnose.evidence import Evidence, EvidenceSettings, analyse  # noqa: F401
from workbench.diagnose.evidence_lines import peaks as line_peaks
from workbench.diagnose.library import EffectLibrary, default_library
from workbench.diagnose.loop_claims import (
    _claim_faults,
    _effect_reports,
    _enforce_claims,
    _heldout_mse,
    _local_rows,
    _local_table,
    _nl_stderr,
    _unexplained,
)
from workbench.diagnose.loop_results import CHANNELS, Diagnosis, EffectReport, Unexplained, _isnum, _num
from workbench.diagnose.loop_settings import DiagnoseSettings, LibrarySettings, ReportSettings
from workbench.diagnose.loop_threads import _chunks_for, one_blas_thread, torch_threads_for_load
from workbench.diagnose.problem import FitSettings, Problem, run_residuals  # noqa: F401
from workbench.diagnose.selection import SelectionSettings, StepwiseSelection, judge  # noqa: F401

__all__ = [
    "CHANNELS",
    "LibrarySettings",
    "ReportSettings",
    "DiagnoseSettings",
    "EffectReport",
    "Unexplained",
    "Diagnosis",
    "_isnum",
    "_num",
    "_heldout_mse",
    "_nl_stderr",
    "_local_rows",
    "_local_table",
    "Probe",
    "one_blas_thread",
    "torch_threads_for_load",
    "_chunks_for",
    "diagnose",
    "_diagnose",
    "_effect_reports",
    "_claim_faults",
    "_enforce_claims",
    "_unexplained",
]


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
        return line_peaks(self.residuals(config, fit), self.settings.evidence, self.cutoff)


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
    if problem.surrogate_search:
        say(f"searches over input effects lag the model's output ({problem.surrogate_reason or 'fit.surrogate_search'})")
    base_fit = problem.fit(Configuration(), names=[])
    res_before = run_residuals(problem, Configuration(), base_fit)
    ev_before = analyse(res_before, s.evidence, cutoff, model_force=[r.predicted for r in res_before],
                        lowpass=lowpass)
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
    ev_after = analyse(res_after, s.evidence, cutoff, model_force=[r.predicted for r in res_after],
                        lowpass=lowpass)
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
        reference=ref_summary, left_at_budget=list(result.left_at_budget),
        unsettled=_unsettled(final, result.last_table, config, problem.search_notes))


def _unsettled(final: lsq.Fit, table: list[dict], config: Configuration, search_notes: dict) -> list[str]:
    """What did not converge: the crosstalk/drift refits, the final fit, the claimed effects' final searches.

    The refits are the selection's ``settle`` row; the searches, each claimed effect's last final
    refinement of its nonlinear parameters (``problem.search_notes``, :func:`selection_finish.refine`).
    """
    out = [r["note"] for r in table if r.get("effect") == "settle" and not r.get("ok", True) and r.get("note")]
    fp = final.fixed_point
    if fp is not None and not fp.settled:
        out.append(fp.note())
    out += [f"the final search of {a.name} did not converge ({search_notes[a.name]})"
            for a in config.actives if search_notes.get(a.name)]
    return out
