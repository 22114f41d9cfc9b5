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
