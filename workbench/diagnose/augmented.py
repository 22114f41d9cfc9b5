"""The augmented model: the diagnosed leg force model plus its fitted effects, as a LegForceModel.

``wrench(motion)`` is what the load cell would read (the whole chain of
:mod:`workbench.diagnose.chain`, including the ingest's low-pass and the load-cell effects), so
it compares directly with processed data and reproduces the diagnosis's ``mse_after``.
:meth:`AugmentedLegModel.physical` keeps only the effects of the leg in water (servo lag, fluid
and gravity loads) for the simulator and the optimiser: a tunnel's blockage, a load cell's
crosstalk or drift do not push a swimming robot.

Saved as one JSON file (``augmented_model.json``): the base model's spec (any
``load_leg_model`` spec) and the effects with their parameters.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from workbench.diagnose.chain import Active, Configuration, Lowpass, build_design
from workbench.diagnose.library import effect_options, make_effect
from workbench.errors import ModelLoadError
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.motion import LegMotion

SCHEMA = "workbench/augmented-leg-model@1"


class _Batch:
    """The minimal run batch the chain needs: motion and time since the first trigger edge."""

    def __init__(self, motion: LegMotion, time_s: np.ndarray | None):
        self.motion = motion
        b, t = motion.shape
        self.time_s = (np.broadcast_to(np.arange(t) * motion.dt_s, (b, t)) if time_s is None
                       else np.broadcast_to(np.asarray(time_s, float), (b, t)))
        self.dt_s = motion.dt_s


class AugmentedLegModel(LegForceModel):
    """Base model + effects; ``reading=True``: the load-cell reading, else the physical leg only."""

    def __init__(self, base: LegForceModel, base_spec: str, config: Configuration, coefs: dict[str, float],
                 lowpass: Lowpass | None = None, local: dict[str, dict[str, list[float]]] | None = None,
                 reading: bool = True, name: str | None = None, info: dict | None = None):
        self.base = base
        self.base_spec = base_spec
        self.config = config
        self.coefs = dict(coefs)
        self.lowpass = lowpass
        self.local = local or {}
        self.reading = reading
        self.name = name or f"{getattr(base, 'name', 'model')}+{len(config.actives)}fx"
        self.info = dict(info or {})

    # ------------------------------------------------------------------ model
    def physical(self) -> "AugmentedLegModel":
        """The leg in water only: servo lag, fluid and gravity loads; no tunnel, structure or load-cell effects."""
        cfg = Configuration([Active(a.effect, dict(a.nl)) for a in self.config.actives if a.effect.physical])
        keep = {f"{a.name}." for a in cfg.actives}
        coefs = {k: v for k, v in self.coefs.items() if any(k.startswith(p) for p in keep)}
        return AugmentedLegModel(self.base, self.base_spec, cfg, coefs, None, None, reading=False,
                                 name=self.name + "-physical", info=self.info)

    def wrench(self, motion: LegMotion, time_s: np.ndarray | None = None,
               run_ids: list[str] | None = None) -> np.ndarray:
        """Predicted wrench (B, T, 6); ``time_s`` since the first trigger edge (default: from 0).

        ``run_ids`` picks the per-run nuisance values (a flow tone's phase) fitted in the diagnosis.
        """
        cfg = self.config if self.reading else Configuration(
            [a for a in self.config.actives if a.effect.physical])
        batch = _Batch(motion, time_s)
        d = build_design(self.base, batch, cfg, self.coefs, self.lowpass if self.reading else None)
        local = None
        if d.local_names:
            b = motion.shape[0]
            local = {n: np.array([self.local.get(n, {}).get(r, 0.0) for r in (run_ids or [""] * b)], float)
                     for n in d.local_names}
        return d.predict(self.coefs, local)

    def describe(self) -> dict:
        """Base model, effects and parameters."""
        return {"name": self.name, "base": self.base_spec, "reading": self.reading,
                "effects": [{"name": a.name, "nl": a.nl} for a in self.config.actives], "coefs": self.coefs}

    # ------------------------------------------------------------------- disk
    def to_json(self) -> dict:
        """The saved form."""
        return {
            "schema": SCHEMA, "name": self.name, "base": self.base_spec,
            "effects": [{"name": a.name, "nonlinear": dict(a.nl), "options": effect_options(a.effect),
                         "coefs": {k.split(".", 1)[1]: v for k, v in self.coefs.items()
                                   if k.split(".", 1)[0] == a.name}} for a in self.config.actives],
            "lowpass": None if self.lowpass is None else {"cutoff_hz": self.lowpass.cutoff_hz,
                                                          "order": self.lowpass.order},
            "per_run": self.local, "info": self.info,
        }

    def save(self, path: str | Path) -> Path:
        """Write ``path`` (JSON, atomically)."""
        from workbench.atomic import write_json

        path = Path(path)
        write_json(path, self.to_json())
        return path


def load_augmented(path: str | Path, base: LegForceModel | None = None) -> AugmentedLegModel:
    """Read a saved augmented model (a JSON file, or a folder holding ``augmented_model.json``)."""
    from workbench.hydro.legmodel import load_leg_model

    p = Path(path)
    if p.is_dir():
        p = p / "augmented_model.json"
    if not p.is_file():
        raise ModelLoadError("no saved augmented model here", path=p,
                             hint="run `workbench diagnose ... --out DIR` and pass DIR/augmented_model.json")
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ModelLoadError(f"cannot read augmented model ({exc})", path=p) from None
    if doc.get("schema") != SCHEMA:
        raise ModelLoadError(f"not an augmented model (schema {doc.get('schema')!r}, expected {SCHEMA!r})", path=p)
    actives, coefs = [], {}
    for e in doc.get("effects", []):
        actives.append(Active(make_effect(e["name"], e.get("options")), dict(e.get("nonlinear", {}))))
        coefs.update({f"{e['name']}.{k}": float(v) for k, v in e.get("coefs", {}).items()})
    from workbench.diagnose.chain import STAGE_ORDER

    cfg = Configuration(sorted(actives, key=lambda a: STAGE_ORDER[a.effect.stage]))
    lp = doc.get("lowpass")
    base_spec = doc["base"]
    if base is None:
        ref = Path(base_spec)
        if not ref.is_absolute() and (p.parent / ref).exists():
            base_spec_resolved = str(p.parent / ref)
        else:
            base_spec_resolved = base_spec
        base = load_leg_model(base_spec_resolved)
    return AugmentedLegModel(base, base_spec, cfg, coefs, Lowpass(**lp) if lp else None, doc.get("per_run", {}),
                             name=doc.get("name"), info=doc.get("info", {}))
