"""Named physical effects the virtual lab can plant on top of its truth (all off by default).

Each effect is a small class with its physics, its parameters (with defaults and units) and the
place in the chain where it acts:

* ``motion``  - on the leg's motion before the physics (servo lag);
* ``flow``    - on the free stream the leg sees (tunnel blockage, flow unsteadiness);
* ``force``   - on the leg force model (added-mass or drag-coefficient error, circulatory lag,
  link drag, lift, leg weight/buoyancy);
* ``reading`` - on what the load cell reports (structural resonance, crosstalk, sensor drift,
  electrical pickup).

Names, parameter names and definitions are the canonical ones shared with the diagnose effect
library, so a planted effect's parameters can be compared with the recovered ones.
``electrical_pickup`` is virtual-lab only (structure no library effect should explain).

Specs are strings ``name`` or ``name:key=value,key=value`` (``workbench virtual-lab effects``
lists them), or :class:`EffectSpec` objects.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import ClassVar, Iterable, Mapping

import numpy as np
from scipy import signal

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.errors import ParamsError

STAGES = ("motion", "flow", "force", "reading")
_SHORT = tuple(c.split("_")[0] for c in WRENCH_CHANNELS)  # fx, fy, fz, tx, ty, tz


@dataclass(frozen=True)
class Param:
    """One effect parameter: default value, unit and a short description."""

    default: float | str
    unit: str
    help: str


@dataclass(frozen=True)
class EffectSpec:
    """A named effect with its parameter values (what a user asks for and truth.json records)."""

    name: str
    params: Mapping[str, float | str] = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "params", MappingProxyType(dict(sorted(dict(self.params).items()))))

    def spec(self) -> str:
        """The spec string, e.g. ``servo_lag:tau_s=0.04``."""
        if not self.params:
            return self.name
        return self.name + ":" + ",".join(f"{k}={v}" for k, v in self.params.items())

    def to_json(self) -> dict:
        """JSON form for truth.json."""
        return {"name": self.name, "params": dict(self.params)}


class Effect:
    """Base class: subclasses set the class attributes and implement their stage's method."""

    name: ClassVar[str]
    stage: ClassVar[str]
    physics: ClassVar[str]
    params: ClassVar[dict[str, Param]] = {}
    #: order among effects of the same stage (lower first)
    order: ClassVar[int] = 0

    def __init__(self, values: Mapping[str, float | str]):
        self.values = dict(values)

    def __getattr__(self, key):
        values = self.__dict__.get("values", {})
        if key in values:
            return values[key]
        raise AttributeError(key)

    def spec(self) -> EffectSpec:
        """The effect and its resolved parameters."""
        return EffectSpec(self.name, self.values)

    # stage hooks; each effect implements the one for its stage
    def apply_motion(self, theta_deg: np.ndarray, omega_dps: np.ndarray, alpha_dps2: np.ndarray,
                     dt_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Actual joint histories (T, 2) from commanded ones."""
        raise NotImplementedError

    def apply_flow(self, u_mps: np.ndarray, t_s: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Free stream (T,) the leg sees, from the nominal one."""
        raise NotImplementedError

    def force_changes(self, params) -> dict:
        """Changes to the truth's :class:`~workbench.virtual_lab.physics.TruthSettings`."""
        raise NotImplementedError

    def apply_reading(self, wrench: np.ndarray, t_since_edge_s: np.ndarray, t_daq_s: np.ndarray,
                      dt_s: float, rng: np.random.Generator) -> np.ndarray:
        """Load-cell reading (T, 6) from the wrench upstream of this effect."""
        raise NotImplementedError


REGISTRY: dict[str, type[Effect]] = {}


def _register(cls: type[Effect]) -> type[Effect]:
    REGISTRY[cls.name] = cls
    return cls


# ----------------------------------------------------------------------------- motion
@_register
class ServoLag(Effect):
    """First-order servo lag on both joints."""

    name = "servo_lag"
    stage = "motion"
    physics = ("Actual joint angles are a first-order low-pass (time constant tau_s) of the commanded "
               "angles, both joints: tau d(theta)/dt = theta_cmd - theta. Hobby servos: 20-60 ms "
               "(field notes); at 0.65 Hz a 50 ms lag is a 12 degree phase error.")
    params = {"tau_s": Param(0.04, "s", "time constant of the lag")}

    def apply_motion(self, theta_deg, omega_dps, alpha_dps2, dt_s):
        """Exact first-order-hold discretisation of the lag; rates follow from the ODE itself."""
        tau = float(self.tau_s)
        if tau <= 0:
            return theta_deg, omega_dps, alpha_dps2
        e = np.exp(-dt_s / tau)
        u = theta_deg
        # x[k+1] = e x[k] + u[k+1] - e u[k] - tau (1 - e) (u[k+1] - u[k]) / dt  (u linear over the step)
        g = tau * (1 - e) / dt_s
        b, a = [1 - g, g - e], [1.0, -e]
        x = np.empty_like(u)
        for j in range(u.shape[1]):  # start at rest on the first command
            zi = signal.lfiltic(b, a, y=[u[0, j]], x=[u[0, j]])
            x[:, j] = signal.lfilter(b, a, u[:, j], zi=zi)[0]
        omega = (u - x) / tau
        alpha = (omega_dps - omega) / tau
        return x, omega, alpha


# ------------------------------------------------------------------------------- flow
@_register
class TunnelBlockage(Effect):
    """Solid/wake blockage raises the dynamic pressure the leg sees."""

    name = "tunnel_blockage"
    stage = "flow"
    physics = ("Free-stream dynamic pressure raised by (1 + epsilon): U_eff = U sqrt(1 + epsilon). "
               "Maskell: epsilon = 2.5 C_D S / C (C the test-section area), a few % to 12 %.")
    params = {"epsilon": Param(0.08, "", "fractional rise of the dynamic pressure")}

    def apply_flow(self, u_mps, t_s, rng):
        """U sqrt(1 + epsilon)."""
        return u_mps * np.sqrt(1.0 + float(self.epsilon))


@_register
class FlowUnsteadiness(Effect):
    """Free-stream unsteadiness: a pump tone plus coloured turbulence/drift."""

    name = "flow_unsteadiness"
    stage = "flow"
    order = 1
    physics = ("U(t) = U (1 + tone_fraction sin(2 pi tone_hz t + phase) + n(t)), n coloured noise "
               "(white noise through a first-order low-pass at corner_hz) scaled to RMS rms_fraction; "
               "random phase and noise per run. Tunnels: 0.5-1.5 % RMS with pump tones (field notes). "
               "The leg's added mass also feels the flow's acceleration.")
    params = {"rms_fraction": Param(0.01, "", "RMS of the coloured part, relative to U"),
              "tone_hz": Param(1.3, "Hz", "pump tone frequency"),
              "tone_fraction": Param(0.01, "", "pump tone amplitude, relative to U"),
              "corner_hz": Param(0.5, "Hz", "corner of the coloured noise")}

    def apply_flow(self, u_mps, t_s, rng):
        """Tone plus coloured noise of exact RMS over the run."""
        phase = rng.uniform(0, 2 * np.pi)
        white = rng.standard_normal(len(t_s))
        dt = float(np.median(np.diff(t_s))) if len(t_s) > 1 else 1.0
        a = np.exp(-2 * np.pi * float(self.corner_hz) * dt)
        before = rng.standard_normal() * np.sqrt((1 - a) / (1 + a))  # a stationary start
        col = signal.lfilter([1 - a], [1.0, -a], white, zi=[a * before])[0]
        col = col - col.mean()
        rms = np.sqrt(np.mean(col**2))
        col = col * (float(self.rms_fraction) / rms) if rms > 0 else col
        t0 = t_s[0]
        tone = float(self.tone_fraction) * np.sin(2 * np.pi * float(self.tone_hz) * (t_s - t0) + phase)
        return u_mps * (1.0 + tone + col)


# ------------------------------------------------------------------------------ force
@_register
class AddedMassError(Effect):
    """Extra added mass on the web normal."""

    name = "added_mass_error"
    stage = "force"
    physics = "Extra added mass on the web normal: dF_n = -delta_kg a_n (a_n: Q's acceleration along the web normal)."
    params = {"delta_kg": Param(0.05, "kg", "extra added mass")}

    def force_changes(self, params):
        """Adds to ``extra_added_mass_kg``."""
        return {"extra_added_mass_kg": params.extra_added_mass_kg + float(self.delta_kg)}


@_register
class DragCoefficientError(Effect):
    """Extra normal drag on the web."""

    name = "drag_coefficient_error"
    stage = "force"
    physics = "Extra normal drag: dF_n = 0.5 rho S delta_c |V_n| V_n (V_n: water velocity relative to Q along the normal)."
    params = {"delta_c": Param(0.3, "", "extra drag coefficient on S = 36 cm^2")}

    def force_changes(self, params):
        """Adds to ``extra_normal_drag_c``."""
        return {"extra_normal_drag_c": params.extra_normal_drag_c + float(self.delta_c)}


@_register
class CirculatoryLag(Effect):
    """First-order lag of the circulatory force with a convective time constant."""

    name = "circulatory_lag"
    stage = "force"
    physics = ("The circulatory (drag/normal) force passes a first-order lag with tau = tau_chords c / "
               "max(|V_rel|, 0.05 m/s), c = 0.06 m (for truth=ef: the EF's drag term; for truth=rich: "
               "its already Wagner-lagged normal force).")
    params = {"tau_chords": Param(2.0, "chords", "time constant in convective times c/|V_rel|")}

    def force_changes(self, params):
        """Sets ``series_lag_tau_chords``."""
        return {"series_lag_tau_chords": float(self.tau_chords)}


@_register
class LinkDrag(Effect):
    """Cross-flow drag of thigh and calf."""

    name = "link_drag"
    stage = "force"
    physics = ("Drag of thigh and calf: per unit length 0.5 rho (cd_d_m) |V_n| V_n normal to the link, "
               "integrated along O-C (thigh) and B to the web's near edge (calf).")
    params = {"cd_d_m": Param(0.01, "m", "drag coefficient times link diameter")}

    def force_changes(self, params):
        """Adds to ``extra_link_cd_d_m``."""
        return {"extra_link_cd_d_m": params.extra_link_cd_d_m + float(self.cd_d_m)}


@_register
class Lift(Effect):
    """Lift on the web from the flow along it."""

    name = "lift"
    stage = "force"
    physics = ("Lift on the web from its tangential relative flow, 0.5 rho S cl |V| V_t, turned to the "
               "web normal (acts at Q).")
    params = {"cl": Param(0.5, "", "lift coefficient")}

    def force_changes(self, params):
        """Adds to ``lift_cl``."""
        return {"lift_cl": params.lift_cl + float(self.cl)}


@_register
class LegWeightBuoyancy(Effect):
    """Net weight/buoyancy of the leg at a point on the hip-to-Q line."""

    name = "leg_weight_buoyancy"
    stage = "force"
    physics = ("A vertical force net_n (N, + up) at distance arm_m from the hip along the hip-to-Q line: "
               "an fz offset and a pose-dependent tx.")
    params = {"net_n": Param(-0.05, "N", "net vertical force, + up (buoyancy minus weight)"),
              "arm_m": Param(0.1, "m", "distance from the hip along the hip-to-Q line")}

    def force_changes(self, params):
        """Appends to ``point_loads``."""
        return {"point_loads": tuple(params.point_loads) + ((float(self.net_n), float(self.arm_m)),)}


# ---------------------------------------------------------------------------- reading
@_register
class StructuralResonance(Effect):
    """A lightly damped mode of the mount between leg and load cell."""

    name = "structural_resonance"
    stage = "reading"
    order = 0
    physics = ("Reading = true wrench through a second-order mode wn^2/(s^2 + 2 zeta wn s + wn^2), "
               "wn = 2 pi f_n_hz (first-order-hold discretisation), all six channels. Keep f_n below the "
               "6 Hz filter cutoff (3-5 Hz) for it to survive ingest.")
    params = {"f_n_hz": Param(4.0, "Hz", "natural frequency"), "zeta": Param(0.1, "", "damping ratio")}

    def apply_reading(self, wrench, t_since_edge_s, t_daq_s, dt_s, rng):
        """Filter each channel from its steady state at the first sample."""
        wn = 2 * np.pi * float(self.f_n_hz)
        b, a, _ = signal.cont2discrete(([wn**2], [1.0, 2 * float(self.zeta) * wn, wn**2]), dt_s, method="foh")
        b = np.ravel(b)
        zi = signal.lfilter_zi(b, a)
        out = np.empty_like(wrench)
        for j in range(wrench.shape[1]):
            out[:, j] = signal.lfilter(b, a, wrench[:, j], zi=zi * wrench[0, j])[0]
        return out


@_register
class LoadcellCrosstalk(Effect):
    """Uncorrected crosstalk between load-cell channels."""

    name = "loadcell_crosstalk"
    stage = "reading"
    order = 1
    physics = ("Reading = (I + X) @ true wrench, X off-diagonal; parameter x_<to>_<from> (e.g. x_fx_fy) is "
               "the fraction of channel <from> read on channel <to>. Six-axis cells: 1-5 % (field notes). "
               "Without parameters: x_fy_fz = 0.03 and x_fz_fy = 0.02.")
    params = {"x_<to>_<from>": Param(0.03, "", "fraction of <from> read on <to> (fx fy fz tx ty tz)")}
    DEFAULTS = {"x_fy_fz": 0.03, "x_fz_fy": 0.02}

    def matrix(self) -> np.ndarray:
        """I + X."""
        m = np.eye(6)
        for key, v in self.values.items():
            to, frm = key.split("_")[1:3]
            m[_SHORT.index(to), _SHORT.index(frm)] += float(v)
        return m

    def apply_reading(self, wrench, t_since_edge_s, t_daq_s, dt_s, rng):
        """(I + X) @ wrench per sample."""
        return wrench @ self.matrix().T


@_register
class SensorDrift(Effect):
    """Linear zero drift of the load cell during a run."""

    name = "sensor_drift"
    stage = "reading"
    order = 2
    physics = ("Reading drifts linearly with time since the run's first trigger edge: "
               "+ rate_<channel>_per_s max(t - t_edge0, 0), per channel (e.g. rate_fz_n_per_s, in N/s or N m/s). "
               "Temperature drift of the bridge (field notes). Without parameters: rate_fz_n_per_s = 0.002.")
    params = {"rate_<channel>_per_s": Param(0.002, "N/s or N m/s", "drift rate of <channel> (fx_n ... tz_nm)")}
    DEFAULTS = {"rate_fz_n_per_s": 0.002}

    def apply_reading(self, wrench, t_since_edge_s, t_daq_s, dt_s, rng):
        """Add rate x (t - t_edge0) to each named channel."""
        out = wrench.copy()
        for key, v in self.values.items():
            ch = key[len("rate_"):-len("_per_s")]
            out[:, WRENCH_CHANNELS.index(ch)] += float(v) * np.maximum(t_since_edge_s, 0.0)
        return out


@_register
class ElectricalPickup(Effect):
    """Mains-like pickup on the readings, locked to nothing the rig does (virtual lab only)."""

    name = "electrical_pickup"
    stage = "reading"
    order = 3
    physics = ("A sinusoid of f_hz added to the readings of the listed channels on the DAQ clock, random "
               "phase per run: amplitude_n on force channels, amplitude_n x 0.05 m on torque channels. "
               "Not in the diagnose library: it must be reported as unexplained, never misnamed.")
    params = {"f_hz": Param(2.7, "Hz", "pickup frequency"),
              "amplitude_n": Param(0.01, "N", "amplitude on force channels"),
              "channels": Param("fy_n+fz_n", "", "channels, joined with '+'")}

    def apply_reading(self, wrench, t_since_edge_s, t_daq_s, dt_s, rng):
        """Add the sinusoid."""
        phase = rng.uniform(0, 2 * np.pi)
        wave = np.sin(2 * np.pi * float(self.f_hz) * (t_daq_s - t_daq_s[0]) + phase)
        out = wrench.copy()
        for ch in str(self.channels).split("+"):
            amp = float(self.amplitude_n) * (0.05 if ch.endswith("_nm") else 1.0)
            out[:, WRENCH_CHANNELS.index(ch)] += amp * wave
        return out


# ------------------------------------------------------------------------------ parsing
def _canonical_key(name: str, key: str) -> str | None:
    """Map a user's parameter key onto the canonical one (None if the effect has no such key)."""
    cls = REGISTRY[name]
    if key in cls.params and "<" not in key:
        return key
    if name == "loadcell_crosstalk":
        m = re.fullmatch(r"x_([a-z]{2})(?:_nm?|)_([a-z]{2})(?:_nm?|)", key)
        if m and m.group(1) in _SHORT and m.group(2) in _SHORT and m.group(1) != m.group(2):
            return f"x_{m.group(1)}_{m.group(2)}"
    if name == "sensor_drift":
        m = re.fullmatch(r"rate_([a-z]{2})(_nm?)?_per_s", key)
        if m and m.group(1) in _SHORT:
            return f"rate_{WRENCH_CHANNELS[_SHORT.index(m.group(1))]}_per_s"
    return None


def _value(name: str, key: str, raw) -> float | str:
    if key == "channels":
        chans = raw if isinstance(raw, str) else "+".join(raw)
        chans = chans.replace("|", "+").replace(" ", "")
        for ch in chans.split("+"):
            if ch not in WRENCH_CHANNELS:
                raise ParamsError(f"effect {name}: unknown channel {ch!r}", hint=f"one of {', '.join(WRENCH_CHANNELS)}")
        return chans
    try:
        v = float(raw)
    except (TypeError, ValueError):
        raise ParamsError(f"effect {name}: parameter {key} = {raw!r} is not a number") from None
    if not np.isfinite(v):
        raise ParamsError(f"effect {name}: parameter {key} must be finite")
    return v


def parse_effect(spec: str | EffectSpec | Mapping) -> Effect:
    """Build an effect from ``"name:key=value,..."``, an :class:`EffectSpec` or ``{"name":..., "params":...}``."""
    if isinstance(spec, Effect):
        return spec
    name, given = _spec_parts(spec)
    name = name.strip()
    if name not in REGISTRY:
        raise ParamsError(f"unknown effect {name!r}", hint=f"known: {', '.join(sorted(REGISTRY))}")
    cls = REGISTRY[name]
    values = _given_values(name, given)
    if not values and hasattr(cls, "DEFAULTS"):
        values = dict(cls.DEFAULTS)
    for key, p in cls.params.items():
        if "<" not in key:
            values.setdefault(key, p.default)
    _check(name, values)
    return cls(values)


def _spec_parts(spec: str | EffectSpec | Mapping) -> tuple[str, dict[str, object]]:
    """The effect's name (unstripped) and its given parameters, from any of the spec forms."""
    if isinstance(spec, str):
        return _spec_text_parts(spec)
    if isinstance(spec, EffectSpec):
        return spec.name, dict(spec.params)
    if isinstance(spec, Mapping):
        return str(spec.get("name", "")), dict(spec.get("params") or {})
    raise ParamsError(f"not an effect spec: {spec!r}")


def _spec_text_parts(spec: str) -> tuple[str, dict[str, object]]:
    """Name and ``key=value`` pairs (as text) of ``"name:key=value,..."``."""
    name, _, rest = spec.strip().partition(":")
    given: dict[str, object] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq:
            raise ParamsError(f"effect spec {spec!r}: expected key=value, got {item!r}",
                              hint="e.g. servo_lag:tau_s=0.04")
        given[key.strip()] = val.strip()
    return name, given


def _given_values(name: str, given: Mapping[str, object]) -> dict[str, float | str]:
    """The given parameters under their canonical keys, checked and converted (unknown keys refused)."""
    values: dict[str, float | str] = {}
    for key, raw in given.items():
        canon = _canonical_key(name, key)
        if canon is None:
            known = ", ".join(REGISTRY[name].params)
            raise ParamsError(f"effect {name}: unknown parameter {key!r}", hint=f"parameters: {known}")
        values[canon] = _value(name, canon, raw)
    return values


def _check(name: str, values: dict) -> None:
    positive = {"servo_lag": ["tau_s"], "circulatory_lag": ["tau_chords"], "structural_resonance": ["f_n_hz", "zeta"],
                "flow_unsteadiness": ["corner_hz"], "electrical_pickup": ["f_hz"]}
    for key in positive.get(name, []):
        if float(values[key]) <= 0:
            raise ParamsError(f"effect {name}: {key} must be positive, got {values[key]}")
    if name == "tunnel_blockage" and float(values["epsilon"]) <= -1:
        raise ParamsError(f"effect {name}: epsilon must be > -1")
    if name == "flow_unsteadiness" and float(values["rms_fraction"]) < 0:
        raise ParamsError(f"effect {name}: rms_fraction must be >= 0")


def parse_effects(specs: Iterable[str | EffectSpec | Mapping] | None) -> list[Effect]:
    """Parse several specs; an effect name may appear once."""
    out = [parse_effect(s) for s in (specs or ())]
    names = [e.name for e in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ParamsError(f"effect {dup[0]!r} given more than once", hint="give all its parameters in one spec")
    return out


def by_stage(effects: Iterable[Effect], stage: str) -> list[Effect]:
    """The effects acting at ``stage``, in their order."""
    return sorted((e for e in effects if e.stage == stage), key=lambda e: e.order)


def describe_all() -> list[dict]:
    """Every effect with stage, physics and parameters (for the CLI and the docs)."""
    return [{"name": c.name, "stage": c.stage, "physics": c.physics,
             "params": {k: {"default": p.default, "unit": p.unit, "help": p.help} for k, p in c.params.items()}}
            for c in REGISTRY.values()]
