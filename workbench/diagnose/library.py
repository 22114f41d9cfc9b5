"""Candidate effects as composable feature libraries (after pysindy's feature libraries).

An :class:`Effect` is one physical mechanism the diagnosed model may lack, with the canonical
name and parameters of the effect table (docs/diagnose.md). It acts at one *stage* of the
chain from commanded motion to load-cell reading:

``input``   changes the motion the model sees (servo lag);
``force``   adds fluid or gravity loads: linear terms ``param * column`` computed from the
            kinematics, a fixed term (circulatory lag), or per-run columns (flow tone);
``filter``  passes the wrench through a linear filter (structural resonance);
``sensor``  acts in the load cell: crosstalk between channels, drift.

Linear parameters are fitted by weighted least squares on the columns; nonlinear ones (a time
constant, a frequency) by a search that wraps the linear fit (:class:`SearchParam`). Effects
name their terms readably (:meth:`Effect.get_feature_names`) and compose with ``+`` into an
:class:`EffectLibrary`, the candidate set the selection draws from.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from workbench.hydro.motion import LegMotion

STAGES = ("input", "force", "filter", "sensor")


@dataclass(frozen=True)
class SearchParam:
    """A nonlinear parameter: its search grid (coarse, then refined within ``bounds``)."""

    name: str
    grid: tuple[float, ...]
    bounds: tuple[float, float]
    log: bool = False


@dataclass
class Terms:
    """What an effect adds at its stage for one batch: linear columns, a fixed part, per-run columns.

    Columns are wrenches ``(B, T, 6)`` of a unit parameter; ``support`` lists the channels in
    which each column can be nonzero (crosstalk and drift touch one channel each).
    """

    names: list[str] = field(default_factory=list)
    cols: list[np.ndarray] = field(default_factory=list)
    support: list[np.ndarray] = field(default_factory=list)
    fixed: np.ndarray | None = None
    local_names: list[str] = field(default_factory=list)
    local: list[np.ndarray] = field(default_factory=list)


class Context:
    """What effects see of one batch of runs under one configuration (motion after input effects)."""

    def __init__(self, rs, model, motion: LegMotion, geometry, rho_kgpm3: float = 1000.0):
        self.rs = rs
        self.model = model
        self.motion = motion
        self.geometry = geometry
        self.rho = rho_kgpm3
        self._flow_cache: dict[float, np.ndarray] = {}

    @property
    def dt_s(self) -> float:
        """Tick interval."""
        return self.motion.dt_s

    @property
    def time_s(self) -> np.ndarray:
        """(B, T) time since the run's first trigger edge."""
        return self.rs.time_s

    @cached_property
    def kin(self):
        """Kinematics of the (transformed) motion."""
        from workbench.diagnose.flowterms import LegKinematics

        return LegKinematics(self.motion, self.geometry, self.rho)

    @cached_property
    def base(self) -> np.ndarray:
        """The diagnosed model's wrench on the (transformed) motion."""
        return np.asarray(self.model.wrench(self.motion), float)

    def wrench_at_flow(self, factor: float) -> np.ndarray:
        """The model's wrench with every flow speed scaled by ``factor`` (cached)."""
        if factor == 1.0:
            return self.base
        if factor not in self._flow_cache:
            m = self.motion
            scaled = LegMotion(m.dt_s, m.theta_h_deg, m.theta_k_deg, m.omega_h_dps, m.omega_k_dps,
                               m.flow_speed_mps * factor, m.alpha_h_dps2, m.alpha_k_dps2)
            self._flow_cache[factor] = np.asarray(self.model.wrench(scaled), float)
        return self._flow_cache[factor]


ALL_CHANNELS = np.ones(6, bool)


class Effect:
    """Base class of candidate effects; subclasses set the class attributes and one or two hooks."""

    #: canonical snake_case name (the effect table)
    name: str = ""
    stage: str = "force"
    #: part of the physical leg (kept in the model handed to the simulator); rig artefacts are not
    physical: bool = True
    #: the effect's formula in one line (report and docs)
    formula: str = ""
    #: nonlinear parameters found by search
    search: tuple[SearchParam, ...] = ()
    #: drop individually insignificant linear terms after selection (crosstalk entries, drift channels)
    prunable: bool = False
    #: needs a frequency proposed by the residual evidence (a narrowband peak) to be a candidate
    needs_peak: bool = False

    # ------------------------------------------------------------------ composition
    def __add__(self, other: "Effect | EffectLibrary") -> "EffectLibrary":
        return EffectLibrary([self]) + other

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"

    def get_feature_names(self) -> list[str]:
        """Readable names of this effect's terms (``effect: formula``)."""
        names = [f"{self.name}.{p}" for p in self.linear_names()]
        names += [f"{self.name}.{s.name} (searched)" for s in self.search]
        return [f"{n}  [{self.formula}]" for n in names] or [f"{self.name}  [{self.formula}]"]

    def linear_names(self) -> list[str]:
        """Names of the linear parameters (a crosstalk or drift effect lists every entry it may fit)."""
        return []

    def default_nl(self) -> dict[str, float]:
        """Starting values of the nonlinear parameters."""
        return {s.name: float(np.median(s.grid)) for s in self.search}

    # ----------------------------------------------------------------------- hooks
    def transform_motion(self, motion: LegMotion, nl: dict) -> LegMotion:
        """Input stage: the motion the leg really made."""
        return motion

    def force_terms(self, ctx: Context, nl: dict) -> Terms:
        """Force stage: linear columns, fixed part and per-run columns."""
        return Terms()

    def filter_wrench(self, w: np.ndarray, dt_s: float, nl: dict) -> np.ndarray:
        """Filter stage: the wrench (..., B, T, 6) through the effect (linear in ``w``)."""
        return w

    def sensor_terms(self, ctx: Context, nl: dict, prediction: np.ndarray) -> Terms:
        """Sensor stage: columns that may depend on the predicted true wrench."""
        return Terms()

    def canonical_params(self, coefs: dict[str, float], nl: dict[str, float],
                         cov: dict[tuple[str, str], float], local: dict | None = None) -> tuple[dict, dict]:
        """Canonical parameters and their standard errors from the fitted values.

        ``cov`` holds the covariance of linear and (linearised) nonlinear parameters by name
        pair; ``local`` the per-run values and weights of per-run columns.
        """
        params = {**nl, **coefs}
        se = {k: float(np.sqrt(max(cov.get((k, k), np.nan), 0.0))) if (k, k) in cov else float("nan")
              for k in params}
        return params, se

    #: physically plausible range of each canonical parameter (a fit outside absorbs something else)
    ranges: dict[str, tuple[float, float]] = {}

    def implausible(self, params: dict) -> str | None:
        """Why the fitted canonical parameters are not this effect (None when they are plausible)."""
        for k, v in params.items():
            rng = self.ranges.get(k) or next((r for pat, r in self.ranges.items()
                                              if pat.endswith("*") and k.startswith(pat[:-1])), None)
            if rng and v is not None and np.isfinite(v) and not rng[0] <= v <= rng[1]:
                return f"{k} = {v:.3g} is outside the plausible range [{rng[0]:g}, {rng[1]:g}]"
        return None

    def null_variants(self, nl: dict) -> list[dict]:
        """Parameter values that should explain nothing (the null of per-run nuisance fits)."""
        return []


class EffectLibrary:
    """A composable set of candidate effects (``a + b + c``)."""

    def __init__(self, effects: list[Effect] | None = None):
        self.effects: list[Effect] = list(effects or [])
        names = [e.name for e in self.effects]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            from workbench.errors import ModelError

            raise ModelError(f"effect library lists {sorted(dup)} twice")

    def __add__(self, other: "Effect | EffectLibrary") -> "EffectLibrary":
        extra = other.effects if isinstance(other, EffectLibrary) else [other]
        return EffectLibrary(self.effects + list(extra))

    def __iter__(self):
        return iter(self.effects)

    def __len__(self) -> int:
        return len(self.effects)

    def __getitem__(self, name: str) -> Effect:
        for e in self.effects:
            if e.name == name:
                return e
        raise KeyError(name)

    def names(self) -> list[str]:
        """Effect names in library order."""
        return [e.name for e in self.effects]

    def get_feature_names(self) -> list[str]:
        """Every term of every effect, readable."""
        return [n for e in self.effects for n in e.get_feature_names()]

    def without(self, *names: str) -> "EffectLibrary":
        """The library less some effects."""
        return EffectLibrary([e for e in self.effects if e.name not in names])


def registry() -> dict[str, type[Effect]]:
    """Every library effect class by canonical name."""
    from workbench.diagnose.effects_fluid import FLUID_EFFECTS
    from workbench.diagnose.effects_rig import RIG_EFFECTS

    return {cls.name: cls for cls in (*FLUID_EFFECTS, *RIG_EFFECTS)}


def effect_options(effect: Effect) -> dict:
    """Constructor options of an effect (JSON-serialisable), so a saved model rebuilds it exactly."""
    if effect.name == "loadcell_crosstalk":
        return {"pairs": [list(p) for p in effect.pairs], "aliases": dict(effect.aliases)}
    if effect.name == "link_drag":
        return {"x_m": effect.x_m, "quadrature": effect.quadrature}
    if effect.name == "circulatory_lag":
        return {"c_r": effect.c_r, "chord_m": effect.chord_m, "speed_floor_mps": effect.floor}
    if effect.name == "wagner_lag":
        return {"chord_m": effect.chord_m, "speed_floor_mps": effect.floor, "quadrature": effect.quadrature,
                "time_scale": effect.time_scale}
    if effect.name in ("link_inertia", "link_weight_buoyancy"):
        return {"x_m": effect.x_m, "quadrature": effect.quadrature}
    if effect.name == "normal_force_law":
        return {"quadrature": effect.quadrature}
    if effect.name == "added_mass_kc":
        return {"exponent": effect.exponent}
    return {}


def make_effect(name: str, options: dict | None = None) -> Effect:
    """Build a library effect by name with its options."""
    from workbench.errors import ModelError

    reg = registry()
    if name not in reg:
        raise ModelError(f"unknown effect {name!r}", hint=f"known: {', '.join(sorted(reg))}")
    opts = dict(options or {})
    if name == "loadcell_crosstalk" and "pairs" in opts:
        opts["pairs"] = [tuple(p) for p in opts["pairs"]]
    return reg[name](**opts)


def default_library(names: list[str] | None = None, link_x_m: float = 0.01, link_quadrature: int = 4,
                    circulatory_c_r: float = 0.7) -> EffectLibrary:
    """The documented library (docs/diagnose.md), optionally restricted to ``names``."""
    reg = registry()
    names = list(reg) if not names else list(names)
    links = {"x_m": link_x_m, "quadrature": link_quadrature}
    opts = {"link_drag": links, "link_inertia": links, "link_weight_buoyancy": links,
            "circulatory_lag": {"c_r": circulatory_c_r}}
    return EffectLibrary([make_effect(n, opts.get(n)) for n in names])


def truth_reference(truth: dict, ef_params=None) -> dict[str, dict[str, float]]:
    """The canonical parameters a virtual campaign's rich truth gives the library's effects, with the EF as base.

    ``truth`` is the ``truth`` block of a virtual campaign's ``truth.json`` (what
    ``TrueLegModel.describe()`` writes); the values are what a perfect diagnosis of the EF on that
    campaign would report, for the report to show beside the fitted ones. Terms the library does
    not hold exactly are mapped to their nearest reading and say so in ``notes``: the links'
    added mass acts along their normal only, while ``link_inertia.m_kgpm`` takes structure and
    added mass on the whole acceleration; the lateral force is a fraction of the *lagged* normal
    force in the truth. Returns ``{}`` for a truth other than ``rich``.
    """
    from workbench.hydro.ef import EFParams

    if truth.get("truth") != "rich":
        return {}
    p = dict(truth.get("params", {}))
    geo = dict(truth.get("geometry", {}))
    ef = ef_params or EFParams()
    rho, g = p.get("rho_kgpm3", 1000.0), p.get("gravity_mps2", 9.81)
    side = geo.get("web_side_m", 0.06)
    m_a = rho * p.get("added_mass_coeff", 0.579) * np.pi / 4 * side ** 3
    web = p.get("web_mass_kg", 0.01)
    c_n = p.get("c_n90", 1.17)
    frac = p.get("circulatory_fraction", 1.0) if p.get("lag", "wagner") == "wagner" else 0.0
    amps = p.get("wagner_amplitudes", (0.165, 0.335))
    rates = p.get("wagner_rates", (0.0455, 0.3))
    thigh_len = geo.get("oc_m", 0.125)
    calf_len = geo.get("bq_over_bc", 2.5) * geo.get("oa_m", 0.035) - side / 2
    d = p.get("link_diameter_m", 0.006)
    added_per_len = p.get("link_added_mass_coeff", 1.0) * rho * np.pi * d * d / 4
    structure = (p.get("thigh_mass_kg", 0.02) + p.get("calf_mass_kg", 0.012)) / (thigh_len + calf_len)
    net = {k: (rho * p.get(f"{k}_volume_m3", 0.0) - p.get(f"{k}_mass_kg", 0.0)) * g for k in ("thigh", "calf", "web")}
    out = {
        "normal_force_law": {"c_n90": c_n},
        "drag_coefficient_error": {"delta_c": -ef.c_r + p.get("extra_normal_drag_c", 0.0)},
        "wagner_lag": {"a_slow": c_n * frac * amps[0], "a_fast": c_n * frac * amps[1],
                       "tau_slow_chords": 1 / (2 * rates[0]), "tau_fast_chords": 1 / (2 * rates[1])},
        "rotating_added_mass": {"m_a_kg": m_a if p.get("rotating_added_mass", True) else 0.0},
        "added_mass_kc": {"m_kc_kg": m_a * p.get("kc_gain", 0.0)},
        "added_mass_error": {"delta_kg": m_a + web - ef.added_mass_kg - ef.m_web_kg + p.get("extra_added_mass_kg", 0.0)},
        "link_drag": {"cd_d_m": p.get("link_cd_d_m", 0.0) + p.get("extra_link_cd_d_m", 0.0)},
        "link_inertia": {"m_kgpm": structure + added_per_len, "web_t_kg": web},
        "lateral_force": {"c_lat": p.get("lateral_fraction", 0.0) * c_n},
        "link_weight_buoyancy": {"net_thigh_n": net["thigh"], "net_calf_n": net["calf"], "net_web_n": net["web"],
                                 "net_n": sum(net.values())},
        "leg_weight_buoyancy": {"net_n": sum(net.values())},
        "notes": {"link_inertia.m_kgpm": f"structure {structure:.3g} kg/m on the whole acceleration + added mass "
                                         f"{added_per_len:.3g} kg/m along the links' normal only",
                  "lateral_force.c_lat": "a fraction of the lagged normal force in the truth (the fit sees less)",
                  "added_mass_error.delta_kg": "truth's m_a + web mass - the EF's 2 pi rho a^3 + m_web on a_n"},
    }
    return out
