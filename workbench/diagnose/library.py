"""The effect table: every candidate effect by canonical name, from the package and its plug-ins.

Effects are classes (:class:`~workbench.diagnose.effects.base.Effect`). They come from three
places, read here and nowhere else:

1. the ``workbench.effects`` entry-point group of installed packages
   (``[project.entry-points."workbench.effects"]`` in a ``pyproject.toml``: ``name = "module:Class"``);
2. the modules of :mod:`workbench.diagnose.effects` that define ``EFFECTS``, so the in-tree
   library works when the package metadata is stale (an editable install not reinstalled
   after an effect was added);
3. :func:`register_effect` at run time (a notebook, a test).

One name, one class: two different classes under one name are an error naming both sources.
This module imports no effect module statically (they import :mod:`.effects.base`), so there
is no import cycle between the table and the effects.
"""

from __future__ import annotations

import importlib
import pkgutil
from functools import lru_cache

import numpy as np

from workbench.diagnose.effects.base import (  # noqa: F401 - re-exported: the library's public names
    ALL_CHANNELS,
    STAGES,
    Context,
    Effect,
    EffectLibrary,
    SearchParam,
    Terms,
)
from workbench.errors import ModelError

#: the entry-point group effects register in
ENTRY_POINT_GROUP = "workbench.effects"
#: the package whose modules' ``EFFECTS`` make the in-tree library
IN_TREE_PACKAGE = "workbench.diagnose.effects"

_RUNTIME: dict[str, type[Effect]] = {}


def _check_class(cls, source: str) -> type[Effect]:
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise ModelError(f"{source} is not an Effect class ({cls!r})",
                         hint="an effect subclasses workbench.diagnose.effects.base.Effect")
    if not cls.name or cls.stage not in STAGES:
        raise ModelError(f"effect {cls.__name__} from {source} needs a name and a stage in {STAGES}")
    return cls


def _add(table: dict, sources: dict, cls: type[Effect], source: str) -> None:
    have = table.get(cls.name)
    if have is not None and have is not cls:
        raise ModelError(f"effect {cls.name!r} is registered twice: {sources[cls.name]} and {source}",
                         hint="rename one of them (effect names are unique)")
    table.setdefault(cls.name, cls)
    sources.setdefault(cls.name, source)


@lru_cache(maxsize=1)
def _in_tree() -> tuple[tuple[str, type[Effect]], ...]:
    pkg = importlib.import_module(IN_TREE_PACKAGE)
    out = []
    mods = [importlib.import_module(f"{IN_TREE_PACKAGE}.{info.name}") for info in pkgutil.iter_modules(pkg.__path__)]
    # library order: a module's LIBRARY_RANK (the leg's own physics first, then the rig from command to reading),
    # then its name; a new module without a rank comes after the documented library
    for mod in sorted(mods, key=lambda m: (getattr(m, "LIBRARY_RANK", 100), m.__name__)):
        out += [(f"{mod.__name__}:{c.__name__}", c) for c in getattr(mod, "EFFECTS", ())]
    return tuple(out)


@lru_cache(maxsize=1)
def _entry_points() -> tuple[tuple[str, str, object], ...]:
    from importlib.metadata import entry_points

    eps = sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name)
    out = []
    for ep in eps:
        try:
            out.append((ep.name, f"entry point {ep.name} = {ep.value}", ep.load()))
        except Exception as exc:  # noqa: BLE001 - a broken plug-in is reported by name, below
            out.append((ep.name, f"entry point {ep.name} = {ep.value}", exc))
    return tuple(out)


def refresh() -> None:
    """Read the entry points and the in-tree modules again (after installing a plug-in)."""
    _in_tree.cache_clear()
    _entry_points.cache_clear()


def registry() -> dict[str, type[Effect]]:
    """Every effect class by canonical name: in-tree first (library order), then plug-ins by name.

    An entry point that fails to load is ignored when the in-tree library has its name (stale
    metadata from an older layout); otherwise it is an error naming the entry point.
    """
    table: dict[str, type[Effect]] = {}
    sources: dict[str, str] = {}
    for source, cls in _in_tree():
        _add(table, sources, _check_class(cls, source), source)
    for name, source, obj in _entry_points():
        if isinstance(obj, Exception):
            if name in table:
                continue
            raise ModelError(f"effect plug-in {name!r} does not load ({source}): {type(obj).__name__}: {obj}",
                             hint="fix or uninstall the package that declares it")
        cls = _check_class(obj, source)
        if cls.name != name:
            raise ModelError(f"{source} declares effect {cls.name!r} under the name {name!r}")
        _add(table, sources, cls, source)
    for cls in _RUNTIME.values():
        _add(table, sources, cls, f"register_effect({cls.__module__}.{cls.__name__})")
    return table


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Add an effect class to the table at run time (usable as a class decorator); returns it."""
    _check_class(cls, f"{cls.__module__}.{getattr(cls, '__name__', cls)}")
    known = registry()
    if cls.name in known and known[cls.name] is not cls:
        raise ModelError(f"effect {cls.name!r} is registered already ({known[cls.name].__module__})",
                         hint="rename the new effect")
    _RUNTIME[cls.name] = cls
    return cls


def unregister_effect(name: str) -> None:
    """Remove an effect added by :func:`register_effect` (entry points and in-tree effects stay)."""
    _RUNTIME.pop(name, None)


def effect_options(effect: Effect) -> dict:
    """Constructor options of an effect (JSON-serialisable), so a saved model rebuilds it exactly."""
    return effect.options()


def make_effect(name: str, options: dict | None = None) -> Effect:
    """Build a library effect by name with its options."""
    reg = registry()
    if name not in reg:
        raise ModelError(f"unknown effect {name!r}", hint=f"known: {', '.join(sorted(reg))}")
    try:
        return reg[name].from_options(options)
    except TypeError as exc:
        raise ModelError(f"effect {name!r}: bad options {sorted(dict(options or {}))}: {exc}",
                         hint=f"{name}'s options are the keyword arguments of {reg[name].__name__}") from exc


def default_library(names: list[str] | None = None, link_x_m: float = 0.01, link_quadrature: int = 4,
                    circulatory_c_r: float = 0.7, options: dict[str, dict] | None = None) -> EffectLibrary:
    """The documented library (docs/diagnose.md), optionally restricted to ``names``.

    The keyword settings (``pipelines/diagnose.yaml`` section ``library``) reach the effects that
    name them in :attr:`~workbench.diagnose.effects.base.Effect.library_options`; ``options``
    gives any effect its own constructor options by name (``{"wagner_lag": {"time_scale": 1.2}}``).
    """
    settings = {"link_x_m": link_x_m, "link_quadrature": link_quadrature, "circulatory_c_r": circulatory_c_r}
    reg = registry()
    names = list(reg) if not names else list(names)
    options = dict(options or {})
    unknown = sorted(set(options) - set(reg))
    if unknown:
        raise ModelError(f"library options name unknown effect(s) {unknown}", hint=f"known: {', '.join(sorted(reg))}")
    out = []
    for n in names:
        cls = reg.get(n)
        opts = {kw: settings[key] for key, kw in getattr(cls, "library_options", {}).items() if key in settings}
        opts.update(options.get(n) or {})
        out.append(make_effect(n, opts or None))
    return EffectLibrary(out)


def location_params() -> set[str]:
    """Canonical parameters that locate an effect rather than measure it, over the whole table."""
    return {p for cls in registry().values() for p in cls.location_params}


class TruthView:
    """A virtual campaign's rich truth as effects read it (:meth:`Effect.truth_params`).

    ``p``: the truth's parameters; ``geo``: its geometry; ``ef``: the EF's parameters (the base
    the values are relative to); and the quantities several effects share: ``c_n`` (C_N90),
    ``m_a`` (the plate's added mass, DNV), ``web`` (the web's mass), ``structure_kgpm`` and
    ``link_added_kgpm`` (the links' mass and added mass per length), ``net`` (weight minus
    buoyancy of thigh, calf and web, N, + up).
    """

    def __init__(self, truth: dict, ef_params=None):
        from workbench.hydro.ef import EFParams

        p = self.p = dict(truth.get("params", {}))
        geo = self.geo = dict(truth.get("geometry", {}))
        self.ef = ef_params or EFParams()
        rho, g = p.get("rho_kgpm3", 1000.0), p.get("gravity_mps2", 9.81)
        side = geo.get("web_side_m", 0.06)
        self.m_a = rho * p.get("added_mass_coeff", 0.579) * np.pi / 4 * side ** 3
        self.web = p.get("web_mass_kg", 0.01)
        self.c_n = p.get("c_n90", 1.17)
        thigh_len = geo.get("oc_m", 0.125)
        calf_len = geo.get("bq_over_bc", 2.5) * geo.get("oa_m", 0.035) - side / 2
        d = p.get("link_diameter_m", 0.006)
        self.link_added_kgpm = p.get("link_added_mass_coeff", 1.0) * rho * np.pi * d * d / 4
        self.structure_kgpm = (p.get("thigh_mass_kg", 0.02) + p.get("calf_mass_kg", 0.012)) / (thigh_len + calf_len)
        self.net = {k: (rho * p.get(f"{k}_volume_m3", 0.0) - p.get(f"{k}_mass_kg", 0.0)) * g
                    for k in ("thigh", "calf", "web")}


def truth_reference(truth: dict, ef_params=None) -> dict[str, dict[str, float]]:
    """The canonical parameters a virtual campaign's rich truth gives the library's effects, with the EF as base.

    ``truth`` is the ``truth`` block of a virtual campaign's ``truth.json`` (what
    ``TrueLegModel.describe()`` writes); the values are what a perfect diagnosis of the EF on that
    campaign would report, for the report to show beside the fitted ones. Each effect reads its
    own values (:meth:`Effect.truth_params`); terms the library does not hold exactly are mapped
    to their nearest reading and say so in ``notes`` (``effect.param``: why). Returns ``{}`` for a
    truth other than ``rich``.
    """
    if truth.get("truth") != "rich":
        return {}
    view = TruthView(truth, ef_params)
    out: dict = {}
    notes: dict[str, str] = {}
    for name, cls in registry().items():
        params = cls.truth_params(view)
        if params is None:
            continue
        out[name] = params
        notes.update({f"{name}.{k}": v for k, v in cls.truth_notes(view).items()})
    out["notes"] = notes
    return out
