"""Records of the forward selection: its settings, a fitted candidate, an accepted step, the result.

:class:`SelectionSettings` holds the knobs of ``pipelines/diagnose.yaml`` section ``selection``;
:class:`Candidate` is one effect (or linear pair) fitted at one step, with its held-out test and
verdict; :class:`Step` an accepted candidate with what it beat; :class:`SelectionResult` the chosen
configuration. :func:`record_row` is a candidate's line in the selection record (``diagnosis.json``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workbench.diagnose import lsq
from workbench.diagnose.chain import Active, Configuration
from workbench.diagnose.effects.base import Effect


@dataclass(frozen=True)
class SelectionSettings:
    """Selection knobs (``pipelines/diagnose.yaml`` section ``selection``)."""

    alpha: float = 0.01
    min_gain: float = 0.02
    #: rounds of the greedy selection (a pair claims two effects in one round). 12 since 2 Dec 2026: with
    #: the 22-effect library the EF's misfit alone takes 11-12 claims, and 8 rounds cut off planted
    #: effects still acceptable (a 3 % crosstalk beside a 25 ms dead time at t 8.6); flagged, not silent
    max_effects: int = 12
    #: entries of crosstalk/drift kept when significant at this level (Bonferroni over entries)
    prune_alpha: float = 0.001
    #: a runner-up reaching this share of the winner's held-out gain is reported as an alternative
    ambiguity_ratio: float = 0.7
    refine: bool = True
    #: half-width of the tone-frequency search around a residual peak (Hz)
    tone_window_hz: float = 0.12
    #: Nelder-Mead evaluations per nonlinear parameter in refinements
    refine_evals: int = 12
    #: rounds of the final refinement when two or more effects have searched values (each searched in
    #: turn, which settles slowly where they trade off); values still moving after the last are flagged
    refine_rounds: int = 2
    #: tone candidates tried per step (the strongest residual lines)
    max_peaks: int = 2
    #: half-width (log units) of a warm-started 1-D search around the last optimum
    warm_window: float = 0.7
    #: also try linear effects two at a time (each may hide the other), claimed when the pair's
    #: held-out gain is at least ``pair_margin`` times its better member's alone
    pairs: bool = True
    pair_margin: float = 1.5
    #: a fitted structural mode damped more than this is a delay in disguise, not a mount mode
    #: (mount and sting modes are lightly damped, zeta << 0.3)
    max_mode_zeta: float = 0.3
    #: a flow tone may leave at most this share of its line's excess power (above the floor)
    tone_line_left: float = 0.4
    #: a claim needs its 95 % interval clear of zero (z = 1.96) on at least one magnitude parameter
    interval_z: float = 1.96
    #: greedy paths followed besides the main one: a look-ahead effect (``Effect.lookahead``, a servo
    #: delay) acceptable at a step but passed over is accepted there and the selection goes on; the
    #: path with the better final held-out fit (significant at ``alpha``) wins. 0: greedy only
    lookahead_branches: int = 1
    #: re-search a chosen look-ahead effect's searched values (a servo's delay) each time another effect comes
    #: in, and go on selecting once the final refinement has moved them (an effect the held value hid)
    follow_lookahead: bool = True
    #: a look-ahead effect the paths did not take, but whose own evidence in the data points to values
    #: (``Effect.seed``: a servo's delay at the runs' onsets), is also tried from the first step on; that
    #: path wins only when its final held-out fit beats the others' (significant at ``alpha``)
    seeded_branches: bool = True
    #: a runner-up whose held-out log-likelihood ratio comes within ``tie_ratio`` of the step's pick (and shares
    #: none of its effects) is a near tie: the greedy choice between them is noise. The first ``tie_branches``
    #: near ties of the path that won (greedy or a branch; one level) are accepted in a path of their own, which wins only when its final
    #: held-out fit beats the others' (significant at ``alpha``); a branch behind after its steps is not finished
    tie_branches: int = 1
    tie_ratio: float = 0.98
    #: when no candidate can be claimed at a step, try the refused ones with amplitudes fitted past a zero
    #: bound held at it (a circulatory lag's fast share; ``StepwiseSelection._held``)
    held_fallback: bool = True
    #: effects that ask for it (``Effect.crossfit``: the crosstalk) are judged cross-fitted in this many folds of
    #: parameter sets, the split's held-out sets one of them (``selection_judge.crossfit_judge``); 0 or 1: the split
    judge_folds: int = 3


@dataclass
class Candidate:
    """One candidate effect fitted in one step."""

    effect: Effect
    active: Active
    config: Configuration
    names: list[str]
    fit: lsq.Fit
    test: dict = field(default_factory=dict)
    gain_c: np.ndarray = field(default_factory=lambda: np.zeros(6))
    profile: dict | None = None
    ok: bool = False
    note: str = ""
    #: a second linear effect claimed together with this one (each may hide the other alone)
    partner: Effect | None = None
    #: fitted through the expensive model's surrogate (refitted with the model before a claim)
    surrogate: bool = False

    @property
    def label(self) -> str:
        """Name, with the searched values."""
        nl = ", ".join(f"{k}={v:.3g}" for k, v in self.active.nl.items())
        own = f"{self.effect.name}({nl})" if nl else self.effect.name
        return f"{own} + {self.partner.name}" if self.partner is not None else own

    @property
    def effects(self) -> list[Effect]:
        """The effect, and its partner if any."""
        return [self.effect] + ([self.partner] if self.partner is not None else [])


@dataclass
class Step:
    """An accepted effect with its test and the alternatives it beat."""

    candidate: Candidate
    mse_before: np.ndarray
    mse_after: np.ndarray
    table: list[dict]
    alternatives: list[str]
    #: effects the held-out data cannot tell apart from this one (winner vs runner-up not significant)
    ambiguous_with: list[str] = field(default_factory=list)
    #: the effect claimed together with this one as a pair (the pair gained pair_margin x either alone); None: alone
    partner: str | None = None


@dataclass
class SelectionResult:
    """The chosen configuration, its fit and the record of every step."""

    config: Configuration
    names: list[str]
    fit: lsq.Fit
    steps: list[Step]
    last_table: list[dict]
    #: the selection-record rows of candidates still acceptable when the round budget (``max_effects``) ran
    #: out, judged in one more round that claims nothing; empty when the selection stopped by itself
    left_at_budget: list[dict] = field(default_factory=list)
    #: whether the round budget ran out before the selection stopped by itself
    budget_spent: bool = False
    #: the near ties the path of this result passed over (``tie_branches``), for the selection to follow
    near_ties: list = field(default_factory=list, repr=False)


def record_row(c: Candidate) -> dict:
    """A candidate's line in the selection record."""
    row = {"effect": c.effect.name, "label": c.label + (" (surrogate)" if c.surrogate else ""), "t": c.test["t"],
           "p": c.test["p"], "llr": c.test["llr"], "max_gain": float(c.gain_c.max()), "ok": c.ok, "note": c.note}
    if "folds" in c.test:
        # judged cross-fitted: llr is scaled to the held-out share of the blocks, llr_crossfit is the whole gain
        row.update(folds=c.test["folds"], llr_crossfit=c.test["llr_crossfit"])
    return row

