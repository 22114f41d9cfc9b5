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

This module is learn's I/O edge for saved models (docs/architecture.md, "Who touches files"):
:func:`model_files` turns a model into the bytes of its folder (a command writes them, through
``workbench/atomic.py``), :func:`staged_folder` lays such bytes out in a temporary folder for
MLflow to log, and every read of a saved folder goes through here: :func:`load_model`,
:func:`read_model_head` (is this a learned model's folder?), :func:`read_model_json` (a JSON file
of a model folder, e.g. an ensemble's ``ensemble.json``) and :func:`mlflow_model_folder` (the
model folder inside a downloaded MLflow model).
"""

from __future__ import annotations

import io
import json
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Mapping

import numpy as np

from workbench.errors import ModelLoadError
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.motion import LegMotion
from workbench.learn.config import FEATURES, ModelSettings
from workbench.learn.windows import Normalisation

MODEL_SCHEMA = "workbench/learned-leg-model@1"
#: windows predicted per forward call (memory ~ chunk * seq_len * hidden floats)
CHUNK = 8192


class LearnedLegModel(LegForceModel):
    """A trained window net (FED-LSTM or a variant) behind the leg force model interface."""

    def __init__(self, net, *, model: ModelSettings, seq_len: int, dt_s: float, norm: Normalisation,
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


def model_files(model: LearnedLegModel) -> dict[str, bytes]:
    """The files of a model folder as bytes: ``model.json`` and ``weights.pt`` (the state dict)."""
    import torch

    buf = io.BytesIO()
    torch.save(model.net.state_dict(), buf)
    return {"model.json": (json.dumps(model_record(model), indent=2) + "\n").encode("utf-8"),
            "weights.pt": buf.getvalue()}


def save_model(model: LearnedLegModel, folder: str | Path) -> Path:
    """Write ``model.json`` and ``weights.pt`` into ``folder`` (which must exist; callers use atomic_dir)."""
    folder = Path(folder)
    for name, data in model_files(model).items():
        (folder / name).write_bytes(data)
    return folder


@contextmanager
def staged_folder(files: Mapping[str, bytes]) -> Iterator[Path]:
    """A temporary folder holding ``files`` (relative name -> bytes), removed on leaving: for MLflow to log."""
    with tempfile.TemporaryDirectory(prefix="wb-model-") as tmp:
        root = Path(tmp)
        for name, data in files.items():
            (root / name).parent.mkdir(parents=True, exist_ok=True)
            (root / name).write_bytes(data)
        yield root


def read_model_head(path: str | Path) -> tuple[Path, dict] | None:
    """``(folder, model.json)`` when ``path`` is a folder (or its ``model.json``) with a readable ``model.json``.

    None when there is no ``model.json`` or it is not a JSON object: the caller decides what else
    the path may be.
    """
    p = Path(path)
    if p.is_file() and p.name == "model.json":
        p = p.parent
    spec = p / "model.json"
    if not spec.is_file():
        return None
    try:
        head = json.loads(spec.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return (p, head) if isinstance(head, dict) else None


def read_model_json(folder: str | Path, name: str, *, missing: str) -> Any:
    """The JSON file ``name`` of a saved model folder; ``missing``: the fault when it is not there.

    A missing file or one that is not JSON is a one-line :class:`ModelLoadError` naming the path.
    """
    folder = Path(folder)
    path = folder / name
    if not path.is_file():
        raise ModelLoadError(missing, path=folder)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ModelLoadError(f"{name} is not JSON ({getattr(exc, 'msg', exc)})", path=path) from exc


def mlflow_model_folder(path: str | Path, artifact: str = "leg_model") -> Path:
    """The model folder inside a downloaded registry version: the MLflow model's ``artifact``, or the folder itself.

    A folder with ``model.json`` (a version registered before models were MLflow models) or without
    ``MLmodel`` is returned as it is.
    """
    path = Path(path)
    if (path / "model.json").is_file() or not (path / "MLmodel").is_file():
        return path
    import yaml

    try:
        doc = yaml.safe_load((path / "MLmodel").read_text(encoding="utf-8")) or {}
        rel = doc["flavors"]["python_function"]["artifacts"][artifact]["path"]
    except (OSError, yaml.YAMLError, KeyError, TypeError) as exc:
        raise ModelLoadError(f"an MLflow model without the workbench's {artifact} artifact "
                             f"({type(exc).__name__}: {exc})", path=path / "MLmodel") from None
    return path / rel


def load_model(folder: str | Path, **info) -> LearnedLegModel:
    """Load a model folder written by :func:`save_model` (``info`` adds provenance, e.g. the model URI)."""
    import torch

    from workbench.learn.nets import build_net

    folder = Path(folder)
    spec_path = folder / "model.json"
    if not spec_path.is_file():
        raise ModelLoadError("no model.json: not a trained leg model folder", path=folder)
    try:
        spec = json.loads(spec_path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise ModelLoadError(f"model.json is not JSON ({exc.msg})", path=spec_path) from exc
    if spec.get("schema") != MODEL_SCHEMA:
        raise ModelLoadError(f"unknown model schema {spec.get('schema')!r}", path=spec_path,
                             hint=f"expected {MODEL_SCHEMA}")
    try:
        cfg = ModelSettings(**spec["model"])
        net = build_net(cfg, int(spec["seq_len"]))
        dt_s, norm = float(spec["dt_s"]), Normalisation.from_dict(spec["normalisation"])
    except (KeyError, TypeError, ValueError) as exc:  # a torn or hand-edited model.json: one line
        raise ModelLoadError(f"model.json is incomplete or malformed ({type(exc).__name__}: {exc})",
                             path=spec_path) from None
    try:
        net.load_state_dict(torch.load(folder / "weights.pt", map_location="cpu", weights_only=True))
    except Exception as exc:  # noqa: BLE001 - missing, torn, foreign or mismatched weights: one line for all
        raise ModelLoadError(f"weights.pt does not load ({str(exc).splitlines()[0]})", path=folder) from exc
    return LearnedLegModel(net, model=cfg, seq_len=spec["seq_len"], dt_s=dt_s, norm=norm,
                           info={**spec.get("info", {}), **info}, name=spec.get("name", "lstm"))
