"""The one interface every leg force model implements, and how a model is found by name.

A leg force model maps a batch of joint-angle histories and flow speeds (:class:`LegMotion`) to
the six-channel wrench the load cell would read, ``(B, T, 6)`` in contract channel order
(fx, fy, fz in N; tx, ty, tz in N m), in the load cell's frame (x hip axis, y forward, z up,
origin on the hip axis). Measured data, the EF, the FED-LSTM and augmented models therefore
compare directly, and the full-body simulator uses any of them unchanged.

Models are found through one table, the ``workbench.leg_models`` entry-point group of installed
packages (``[project.entry-points."workbench.leg_models"]`` in ``pyproject.toml``), read here and
nowhere else. An entry's name says its kind:

- ``ef = "workbench.hydro.ef:EmpiricalFormula"``: a name; ``load_leg_model("ef")`` calls the target;
- ``"models:" = "...:load_model_uri"``: a prefix (the name ends in ``:``); the target gets the whole spec;
- ``"path.lstm" = "...:load_path"``: a path loader (the name starts with ``path.``); tried in name order
  for a spec that is an existing path, it returns None when the path is not its kind of model.

:func:`register_loader` / :func:`register_path_loader` add entries at run time (tests, notebooks);
they take precedence over the entry points.
"""

from __future__ import annotations

import abc
import importlib
import re
from functools import lru_cache
from pathlib import Path
from typing import Callable

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.errors import ModelError, ModelLoadError
from workbench.hydro.motion import LegMotion

#: the entry-point group leg force models are declared in
ENTRY_POINT_GROUP = "workbench.leg_models"
#: an entry whose name starts with this is a path loader
PATH_LOADER_PREFIX = "path."
_TARGET = re.compile(r"[A-Za-z_][\w.]*:[A-Za-z_][\w.]*")


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


# run-time additions (register_loader): name -> target, prefix -> target, path-loader targets
_LOADERS: dict[str, str | Callable] = {}
_PREFIX_LOADERS: dict[str, str | Callable] = {}
_PATH_LOADERS: list[str | Callable] = []


def register_loader(name: str, target: str | Callable) -> None:
    """Register ``name`` (or a ``prefix:`` ending in a colon) to a ``module:callable`` path or a callable."""
    if name.endswith(":"):
        _PREFIX_LOADERS[name] = target
    else:
        _LOADERS[name] = target


def register_path_loader(target: str | Callable) -> None:
    """Register a ``module:callable(path)`` that loads a saved model from a path (None: not its kind)."""
    if target not in _PATH_LOADERS:
        _PATH_LOADERS.append(target)


@lru_cache(maxsize=1)
def _entry_points() -> tuple[tuple[str, str], ...]:
    """``(name, "module:attr")`` of every installed ``workbench.leg_models`` entry point, by name."""
    from importlib.metadata import entry_points

    return tuple(sorted({(ep.name, ep.value) for ep in entry_points(group=ENTRY_POINT_GROUP)}))


def refresh() -> None:
    """Read the entry points again (after installing or removing a plug-in package)."""
    _entry_points.cache_clear()


def _source(name: str, target: str | Callable) -> str:
    if callable(target):
        return f"register_loader({name!r}, {getattr(target, '__qualname__', target)!r})"
    return f"entry point {name} = {target} ({ENTRY_POINT_GROUP})"


def table() -> dict[str, dict]:
    """The leg-model table: ``{"names": {...}, "prefixes": {...}, "paths": {...}}``, entry -> target.

    Run-time registrations override entry points of the same name.
    """
    names: dict[str, str | Callable] = {}
    prefixes: dict[str, str | Callable] = {}
    paths: dict[str, str | Callable] = {}
    for name, value in _entry_points():
        if name.startswith(PATH_LOADER_PREFIX):
            paths[name] = value
        elif name.endswith(":"):
            prefixes[name] = value
        else:
            names[name] = value
    names.update(_LOADERS)
    prefixes.update(_PREFIX_LOADERS)
    for i, target in enumerate(_PATH_LOADERS):
        paths.setdefault(f"{PATH_LOADER_PREFIX}runtime-{i}", target)
    return {"names": names, "prefixes": prefixes, "paths": paths}


def _resolve(name: str, target: str | Callable) -> Callable:
    """The callable behind an entry; a broken entry is a one-line ModelLoadError naming it."""
    if callable(target):
        return target
    where = _source(name, target)
    if not _TARGET.fullmatch(target):
        raise ModelLoadError(f"leg-model {where} is not a 'module:callable' path",
                             hint="fix the package's entry point")
    module, _, attr = target.partition(":")
    try:
        obj = importlib.import_module(module)
        for part in attr.split("."):
            obj = getattr(obj, part)
    except ImportError as exc:
        raise ModelLoadError(f"leg-model {where} does not load: {type(exc).__name__}: {exc}",
                             hint="fix or reinstall the package that declares it") from exc
    except AttributeError as exc:
        raise ModelLoadError(f"leg-model {where} does not load: {module} has no {attr!r}",
                             hint="fix or reinstall the package that declares it") from exc
    if not callable(obj):
        raise ModelLoadError(f"leg-model {where} is not callable ({type(obj).__name__})")
    return obj


def load_leg_model(spec: str, **kwargs) -> LegForceModel:
    """Find a leg force model by name (``ef``, ``lstm``, ...), prefixed spec, or saved-model path."""
    t = table()
    if spec in t["names"]:
        return _resolve(spec, t["names"][spec])(**kwargs)
    for prefix in sorted(t["prefixes"], key=len, reverse=True):
        if spec.startswith(prefix):
            return _resolve(prefix, t["prefixes"][prefix])(spec, **kwargs)
    if t["paths"] and Path(spec).exists():
        for name, target in t["paths"].items():
            model = _resolve(name, target)(spec, **kwargs)
            if model is not None:
                return model
    known = ", ".join(sorted(t["names"]) + sorted(t["prefixes"]))
    hint = f"known: {known}" if known else (
        f"no {ENTRY_POINT_GROUP} entry points are installed: run `pip install -e . --no-deps` in the checkout")
    if Path(spec).exists():
        hint = f"{spec} exists but no path loader knows it; {hint}"
    raise ModelError(f"unknown leg force model {spec!r}", hint=hint)
