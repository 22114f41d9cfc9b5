"""What a diagnosis returns: claimed effects, unexplained structure and the :class:`Diagnosis` itself.

Domain records with their ``diagnosis.json`` form (data contract section 4): :class:`EffectReport`
(a claimed effect with intervals, evidence and held-out error reduction), :class:`Unexplained`
(residual structure no library effect explains) and :class:`Diagnosis` (the whole outcome the
command writes out). No files are touched here.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose.augmented import AugmentedLegModel
from workbench.diagnose.evidence_base import Evidence
from workbench.diagnose.loop_settings import DiagnoseSettings

CHANNELS = list(WRENCH_CHANNELS)


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
    #: selection-record rows of candidates still acceptable when the round budget ran out (empty: converged)
    left_at_budget: list[dict] = field(default_factory=list)
    #: sentences on what did not converge: the final fit's passes, the crosstalk/drift refits, the claimed effects'
    #: final searches
    unsettled: list[str] = field(default_factory=list)

    def unfinished(self) -> str | None:
        """One sentence when the selection ran out of rounds with acceptable candidates left (None: it stopped by itself)."""
        if not self.left_at_budget:
            return None
        left = ", ".join(f"{r['label']} (t {r['t']:.1f})" for r in self.left_at_budget)
        return (f"the selection stopped at its budget of {self.settings.selection.max_effects} rounds with "
                f"{len(self.left_at_budget)} acceptable candidate(s) left: {left}; it did not converge "
                "(raise selection.max_effects to go on)")

    def not_converged(self) -> list[str]:
        """Every sentence saying what did not converge: the selection's budget, then :attr:`unsettled` (empty: all did)."""
        return [x for x in (self.unfinished(), *self.unsettled) if x]

    def mse_after_corrected(self) -> dict[str, float] | None:
        """Held-out MSE against the readings corrected by the claimed sensor-side effects (None: none, or one not invertible).

        ``mse_after`` compares the reading with the augmented model's reading, H(M) for a mount
        mode H: what is left there is H(truth - M), the base model's own misfit amplified near the
        mode. Here each held-out run's residual goes back through the claimed filter and sensor
        effects' inverses (:meth:`~workbench.diagnose.effects.base.Effect.reading_inverse`, last
        stage first): the error of the physical model against the readings as a lab would
        correct them with these effects.
        """
        return corrected_heldout_mse(self.residuals_after, self.augmented.config, self.augmented.coefs)

    def to_json(self) -> dict:
        """``diagnosis.json`` (data contract section 4) with extra keys."""
        corrected = self.mse_after_corrected()
        rel = {c: _num(1 - self.mse_after[c] / self.mse_before[c]) if self.mse_before[c] > 0 else 0.0
               for c in CHANNELS}
        return {
            "model": self.model,
            "channels": CHANNELS,
            "mse_before": {c: _num(self.mse_before[c]) for c in CHANNELS},
            "mse_after": {c: _num(self.mse_after[c]) for c in CHANNELS},
            "mse_after_corrected": None if corrected is None else {c: _num(corrected[c]) for c in CHANNELS},
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
            **({"selection_budget": {
                "max_effects": self.settings.selection.max_effects, "converged": False,
                "acceptable_left": [{k: r[k] for k in ("effect", "label", "t", "p", "max_gain") if k in r}
                                    for r in self.left_at_budget],
                "note": self.unfinished()}} if self.left_at_budget else {}),
            **({"fit_convergence": {"converged": False, "notes": list(self.unsettled)}} if self.unsettled else {}),
        }


def corrected_heldout_mse(runs, config, coefs: dict[str, float]) -> dict[str, float] | None:
    """Held-out MSE per channel of the runs' residuals taken back through the config's sensor-side inverses.

    None when the configuration holds no filter or sensor effect, or one whose reading is not
    invertible (its :meth:`~workbench.diagnose.effects.base.Effect.reading_inverse` is None).
    """
    side = [a for a in config.actives if a.effect.stage in ("filter", "sensor")]
    if not side:
        return None
    parts = []
    for r in runs:
        if not r.heldout:
            continue
        x = r.resid
        for a in reversed(side):
            inverse = a.effect.reading_inverse(dict(a.nl), coefs, r.dt_s)
            if inverse is None:
                return None
            x = inverse(x)
        parts.append(x[r.fit])
    if not parts:
        return None
    e = np.concatenate(parts)
    return {c: float((e[:, i] ** 2).mean()) for i, c in enumerate(CHANNELS)}


def _isnum(v) -> bool:
    return isinstance(v, (int, float, np.floating)) and not isinstance(v, bool)


def _num(v):
    if v is None or not _isnum(v):
        return v
    v = float(v)
    return float(f"{v:.6g}") if np.isfinite(v) else None
