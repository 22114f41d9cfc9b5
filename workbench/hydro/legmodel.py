"""The one interface every leg force model implements, and how a model is found by name.

A leg force model maps a batch of joint-angle histories and flow speeds (:class:`LegMotion`) to
the six-channel wrench the load cell would read, ``(B, T, 6)`` in contract channel order
(fx, fy, fz in N; tx, ty, tz in N m), in the load cell's frame (x hip axis, y forward, z up,
origin on the hip axis). Measured data, the EF, the FED-LSTM and augmented models therefore
compare directly, and the full-body simulator uses any of them unchanged.
"""

from __future__ import annotations

import abc
import importlib
from pathlib import Path
from typing import Callable

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.errors import ModelError
from workbench.hydro.motion import LegMotion


class LegForceModel(abc.ABC):
    """Base class of leg force models."""

    #: short name used in file names, metrics and MLflow ("ef", "lstm", ...)
    name: str = "model"
    channels: tuple[str, ...] = WRENCH_CHANNELS

    @abc.abstractmethod
    def wrench(self, motion: LegMotion) -> np.ndarray:
        """Predict the load-cell wrench ``(B, T, 6)`` for the motion batch."""

    def describe(self) -> dict:
        """Parameters worth recording with results (JSON-serialisable)."""
        return {"name": self.name}


#: name -> "module:callable" returning a LegForceModel; packages add their own entries here.
_LOADERS: dict[str, str] = {
    "ef": "workbench.hydro.ef:EmpiricalFormula",
}
#: prefix -> "module:callable(spec)" for parameterised specs (e.g. "models:/name@alias", "file:...")
_PREFIX_LOADERS: dict[str, str] = {}
#: "module:callable(path)" tried in turn for a spec that is an existing path; returns None if not its kind
_PATH_LOADERS: list[str] = []


def register_loader(name: str, target: str) -> None:
    """Register ``name`` (or a ``prefix:`` ending in a colon) to a ``module:callable`` path."""
    if name.endswith(":"):
        _PREFIX_LOADERS[name] = target
    else:
        _LOADERS[name] = target


def register_path_loader(target: str) -> None:
    """Register a ``module:callable(path)`` that loads a saved model from a path (None: not its kind)."""
    if target not in _PATH_LOADERS:
        _PATH_LOADERS.append(target)


def _resolve(target: str) -> Callable:
    module, _, attr = target.partition(":")
    return getattr(importlib.import_module(module), attr)


def load_leg_model(spec: str, **kwargs) -> LegForceModel:
    """Find a leg force model by name (``ef``, ``lstm``, ...), prefixed spec, or saved-model path."""
    _ensure_plugins()
    if spec in _LOADERS:
        return _resolve(_LOADERS[spec])(**kwargs)
    for prefix, target in _PREFIX_LOADERS.items():
        if spec.startswith(prefix):
            return _resolve(target)(spec, **kwargs)
    if _PATH_LOADERS and Path(spec).exists():
        for target in _PATH_LOADERS:
            model = _resolve(target)(spec, **kwargs)
            if model is not None:
                return model
    known = ", ".join(sorted(_LOADERS)) + (", " + ", ".join(sorted(_PREFIX_LOADERS)) if _PREFIX_LOADERS else "")
    raise ModelError(f"unknown leg force model {spec!r}", hint=f"known: {known}")


_PLUGIN_MODULES = (
    "workbench.learn.plugin",
    "workbench.diagnose.plugin",
)


def _ensure_plugins() -> None:
    """Import the light plugin modules of other packages so they can register their loaders."""
    for mod in _PLUGIN_MODULES:
        try:
            importlib.import_module(mod)
        except ModuleNotFoundError as exc:
            if exc.name != mod:
                raise
