"""A trained window net as a :class:`LegForceModel`, and its folder on disk.

``wrench(motion)`` turns a (B, T) joint history into one window of ``seq_len`` ticks per tick
(the model sees the current tick and the ``seq_len - 1`` before it, never the future), predicts
them in large batches and returns (B, T, 6) in newtons and newton-metres. Before the first full
window the history is padded by repeating the first tick (as if the leg had rested there): the
first ``seq_len - 1`` outputs of a run are therefore start-up transients, and evaluation skips
them for every model alike.

The net was trained on one control tick (``dt_s``, 65 Hz in the paper); a motion sampled at
another tick (> 2 % off, e.g. a simulator's 1 ms step) is resampled linearly onto the training
tick, predicted, and interpolated back, so the seq_len-tick window always spans the same time.

The folder holds ``model.json`` (variant, architecture, seq_len, dt_s, normalisation, training
provenance) and ``weights.pt`` (the state dict); see :func:`save_model` / :func:`load_model`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from workbench.errors import ModelError
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.motion import LegMotion
from workbench.learn.config import FEATURES, ModelCfg
from workbench.learn.windows import Normalisation

MODEL_SCHEMA = "workbench/learned-leg-model@1"
#: windows predicted per forward call (memory ~ chunk * seq_len * hidden floats)
CHUNK = 8192


class LearnedLegModel(LegForceModel):
    """A trained window net (FED-LSTM or a variant) behind the leg force model interface."""

    def __init__(self, net, *, model: ModelCfg, seq_len: int, dt_s: float, norm: Normalisation,
                 info: Mapping[str, Any] | None = None, name: str = "lstm"):
        self.net = net.eval()
        self.model_cfg = model
        self.seq_len = int(seq_len)
        self.dt_s = float(dt_s)
        self.norm = norm
        self.info = dict(info or {})
        self.name = name
        self._xm, self._xs, self._ym, self._ys = norm.arrays()
        self._ef = None
        if model.variant == "ef_residual":
            from workbench.hydro.ef import EmpiricalFormula

            self._ef = EmpiricalFormula()

    # -- prediction ---------------------------------------------------------------------------
    def predict_normalised(self, x, ends, offsets=None):
        """Net output (n, 6) for windows ending at rows ``ends`` of a normalised (N, 5) tensor."""
        import torch

        offsets = torch.arange(-self.seq_len + 1, 1) if offsets is None else offsets
        outs = []
        with torch.inference_mode():
            for i in range(0, len(ends), CHUNK):
                e = ends[i:i + CHUNK]
                outs.append(self.net(x[e[:, None] + offsets]))
        return torch.cat(outs) if outs else torch.zeros((0, 6))

    def _net_wrench(self, feats: np.ndarray) -> np.ndarray:
        """Physical net part of the prediction for features (B, T, 5): mu + sd * net (plain) or sd * net."""
        import torch

        b, t, _ = feats.shape
        pad = self.seq_len - 1
        xn = (feats.astype(np.float32) - self._xm) / self._xs
        xn = np.concatenate([np.repeat(xn[:, :1], pad, axis=1), xn], axis=1) if pad else xn
        flat = torch.from_numpy(np.ascontiguousarray(xn.reshape(b * (t + pad), -1)))
        ends = (torch.arange(b)[:, None] * (t + pad) + pad + torch.arange(t)[None, :]).reshape(-1)
        out = self.predict_normalised(flat, ends).numpy().reshape(b, t, -1).astype(np.float64)
        out = out * self._ys
        return out if self._ef is not None else out + self._ym

    def wrench(self, motion: LegMotion) -> np.ndarray:
        """Predicted load-cell wrench (B, T, 6) for the motion batch (causal, see module docstring)."""
        feats = np.stack([motion.flow_speed_mps, motion.theta_h_deg, motion.theta_k_deg,
                          motion.omega_h_dps, motion.omega_k_dps], axis=-1)
        b, t, _ = feats.shape
        if t == 0:
            return np.zeros((b, 0, 6))
        if abs(motion.dt_s - self.dt_s) > 0.02 * self.dt_s and t > 1:
            t_in = np.arange(t) * motion.dt_s
            t_net = np.arange(0.0, t_in[-1] + 0.5 * self.dt_s, self.dt_s)
            res = np.stack([np.stack([np.interp(t_net, t_in, feats[i, :, j]) for j in range(feats.shape[-1])], -1)
                            for i in range(b)])
            out_net = self._net_wrench(res)
            out = np.stack([np.stack([np.interp(t_in, t_net, out_net[i, :, k]) for k in range(6)], -1)
                            for i in range(b)])
        else:
            out = self._net_wrench(feats)
        if self._ef is not None:
            out = out + self._ef.wrench(motion)
        return out

    def describe(self) -> dict:
        """Variant, architecture and provenance (JSON)."""
        return {"name": self.name, "variant": self.model_cfg.variant, "seq_len": self.seq_len, "dt_s": self.dt_s,
                **{k: v for k, v in self.info.items()
                   if k in ("run_id", "model_uri", "model_version", "model_path", "git_commit", "campaigns")}}


def model_record(model: LearnedLegModel) -> dict:
    """The ``model.json`` content."""
    from dataclasses import asdict

    return {"schema": MODEL_SCHEMA, "name": model.name, "model": asdict(model.model_cfg), "seq_len": model.seq_len,
            "dt_s": model.dt_s, "features": list(FEATURES), "padding": "repeat-first-tick",
            "normalisation": model.norm.to_dict(), "info": model.info}


def save_model(model: LearnedLegModel, folder: str | Path) -> Path:
    """Write ``model.json`` and ``weights.pt`` into ``folder`` (which must exist; callers use atomic_dir)."""
    import torch

    folder = Path(folder)
    torch.save(model.net.state_dict(), folder / "weights.pt")
    (folder / "model.json").write_text(json.dumps(model_record(model), indent=2) + "\n", encoding="utf-8")
    return folder


def load_model(folder: str | Path, **info) -> LearnedLegModel:
    """Load a model folder written by :func:`save_model` (``info`` adds provenance, e.g. the model URI)."""
    import torch

    from workbench.learn.nets import build_net

    folder = Path(folder)
    spec_path = folder / "model.json"
    if not spec_path.is_file():
        raise ModelError("no model.json: not a trained leg model folder", path=folder)
    try:
        spec = json.loads(spec_path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ModelError(f"model.json is not JSON ({exc.msg})", path=spec_path) from exc
    if spec.get("schema") != MODEL_SCHEMA:
        raise ModelError(f"unknown model schema {spec.get('schema')!r}", path=spec_path, hint=f"expected {MODEL_SCHEMA}")
    try:
        cfg = ModelCfg(**spec["model"])
        net = build_net(cfg, int(spec["seq_len"]))
        dt_s, norm = float(spec["dt_s"]), Normalisation.from_dict(spec["normalisation"])
    except (KeyError, TypeError, ValueError) as exc:  # a torn or hand-edited model.json: one line
        raise ModelError(f"model.json is incomplete or malformed ({type(exc).__name__}: {exc})", path=spec_path) from None
    try:
        net.load_state_dict(torch.load(folder / "weights.pt", map_location="cpu", weights_only=True))
    except Exception as exc:  # noqa: BLE001 - missing, torn, foreign or mismatched weights: one line for all
        raise ModelError(f"weights.pt does not load ({str(exc).splitlines()[0]})", path=folder) from exc
    return LearnedLegModel(net, model=cfg, seq_len=spec["seq_len"], dt_s=dt_s, norm=norm,
                           info={**spec.get("info", {}), **info}, name=spec.get("name", "lstm"))
