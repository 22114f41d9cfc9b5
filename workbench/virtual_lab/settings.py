"""What the virtual lab can be told: scales, parameter grids and the rig's numbers (pipelines/virtual_lab.yaml).

Defaults here equal the YAML's; the YAML is where a researcher turns the knobs. Paper scale
(Table I of the paper): theta_h_min in {10, -10, -30, -50} deg, theta_k_max in {-20, -40, -60,
-80} deg, theta_h_max = -100 deg, theta_k_min = 80 deg, phi in {pi/3, ..., 5 pi/3} (5 values) and
six frequencies evenly spaced over Table I's [0.3, 0.6] Hz: 4 x 4 x 5 x 6 = 480 sets per flow
speed (Table I's 0.1 Hz interval would give 320, not the paper's 480), 10 cycles each, about
2.9 M control ticks at 65 Hz over the four flow speeds. Demo scale: every (theta_h_min,
theta_k_max) pair with three (f, phi) pairs in a Latin square over f in {0.3, 0.45, 0.6} Hz and
phi in {pi/3, pi, 5 pi/3}: 48 sets per speed, 5 cycles.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import itertools
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

from workbench.contract.columns import TUNNEL_MOTION_PARAMS
from workbench.errors import ParamsError, SettingError

THETA_H_MIN_DEG = (10.0, -10.0, -30.0, -50.0)
THETA_K_MAX_DEG = (-20.0, -40.0, -60.0, -80.0)
FIXED_MOTION = {"theta_h_max_deg": -100.0, "theta_k_min_deg": 80.0, "alpha_rad": 0.0}
PAPER_FREQUENCIES_HZ = (0.3, 0.36, 0.42, 0.48, 0.54, 0.6)
PAPER_PHI_RAD = tuple(k * math.pi / 3 for k in range(1, 6))
DEMO_FREQUENCIES_HZ = (0.3, 0.45, 0.6)
DEMO_PHI_RAD = (math.pi / 3, math.pi, 5 * math.pi / 3)
FLOW_SPEEDS_MPS = (0.0, 0.1, 0.2, 0.3)
FORMS = ("csv", "bin", "mcap", "mixed")


def factorial(axes: Mapping[str, Sequence[float]]) -> list[dict[str, float]]:
    """Every combination of the given axes (first axis slowest), with the fixed motion values filled in."""
    keys = list(axes)
    return [_complete(dict(zip(keys, combo, strict=True))) for combo in itertools.product(*(axes[k] for k in keys))]


def paper_grid() -> list[dict[str, float]]:
    """The 480 parameter sets per flow speed (module docstring)."""
    return factorial({"theta_h_min_deg": THETA_H_MIN_DEG, "theta_k_max_deg": THETA_K_MAX_DEG,
                      "frequency_hz": PAPER_FREQUENCIES_HZ, "phi_rad": PAPER_PHI_RAD})


def demo_grid() -> list[dict[str, float]]:
    """48 sets: each amplitude pair with all three demo frequencies, phases rotated (Latin square)."""
    out = []
    for i, h in enumerate(THETA_H_MIN_DEG):
        for j, k in enumerate(THETA_K_MAX_DEG):
            for q, f in enumerate(DEMO_FREQUENCIES_HZ):
                out.append(_complete({"theta_h_min_deg": h, "theta_k_max_deg": k, "frequency_hz": f,
                                      "phi_rad": DEMO_PHI_RAD[(q + i + j) % 3]}))
    return out


def _complete(p: Mapping[str, float]) -> dict[str, float]:
    out = {k: float(FIXED_MOTION[k]) for k in FIXED_MOTION}
    out.update({k: float(v) for k, v in p.items()})
    missing = [k for k in TUNNEL_MOTION_PARAMS if k not in out]
    unknown = [k for k in out if k not in TUNNEL_MOTION_PARAMS]
    if missing or unknown:
        raise ParamsError(f"grid entry {dict(p)} has missing {missing} / unknown {unknown} parameters",
                            hint=f"use {', '.join(TUNNEL_MOTION_PARAMS)}")
    if out["frequency_hz"] <= 0:
        raise ParamsError(f"grid entry {dict(p)}: frequency_hz must be positive")
    return {k: out[k] for k in TUNNEL_MOTION_PARAMS}


def resolve_grid(grid: Any) -> list[dict[str, float]]:
    """A grid given as "paper" / "demo", a mapping of axes (full factorial) or a list of parameter sets."""
    if grid in (None, "demo"):
        return demo_grid()
    if grid == "paper":
        return paper_grid()
    if isinstance(grid, Mapping):
        return factorial({k: [float(x) for x in (v if isinstance(v, (list, tuple)) else [v])] for k, v in grid.items()})
    if isinstance(grid, (list, tuple)) and grid and all(isinstance(g, Mapping) for g in grid):
        return [_complete(g) for g in grid]
    raise ParamsError(f"cannot read grid {grid!r}",
                        hint="'paper', 'demo', a mapping of parameter lists, or a list of parameter sets")


@dataclass(frozen=True)
class Scale:
    """A named size of campaign."""

    name: str
    grid: str
    cycles: int
    towing_speeds_mps: tuple[float, ...]
    towing_repeats: int


SCALES = {
    "demo": Scale("demo", "demo", 5, (0.05, 0.08, 0.12, 0.16, 0.2, 0.25, 0.3, 0.35), 1),
    "paper": Scale("paper", "paper", 10, tuple(round(0.1 + 0.025 * i, 3) for i in range(11)), 3),
}


@dataclass(frozen=True)
class LoadCellSettings:
    """The six-axis load cell and its DAQ (noise, per-run bias and slow drift, calibration)."""

    model: str = "DMI D6095XA"
    rate_hz: float = 500.0
    full_scale: tuple[float, ...] = (50.0, 50.0, 50.0, 2.0, 2.0, 2.0)
    noise_n: float = 0.01
    noise_nm: float = 0.0005
    bias_n: float = 0.002
    bias_nm: float = 0.0001
    drift_n_per_s: float = 3e-5
    drift_nm_per_s: float = 1.5e-6
    counts_per_n: float = 1e5
    counts_per_nm: float = 2e6
    calibration_coupling: float = 0.01
    start_margin_s: tuple[float, float] = (0.2, 0.6)
    end_margin_s: tuple[float, float] = (0.2, 0.6)


@dataclass(frozen=True)
class ClockSettings:
    """DAQ and recorder clocks against the controller's clock (per run, drawn from these ranges)."""

    daq_drift_ppm: tuple[float, float] = (20.0, 200.0)
    daq_offset_s: tuple[float, float] = (5.0, 4000.0)
    controller_origin_s: tuple[float, float] = (1.0, 900.0)
    recorder_latency_s: tuple[float, float] = (0.0005, 0.004)


@dataclass(frozen=True)
class ControllerSettings:
    """The leg controller: control rate, rest stretches, servo feedback."""

    rate_hz: float = 65.0
    feedback: bool = False
    rest_before_s: float = 1.0
    rest_after_s: float = 0.5
    ease_s: float = 0.4
    feedback_noise_deg: float = 0.05
    feedback_resolution_deg: float = 0.1


@dataclass(frozen=True)
class CarriageSettings:
    """The towing carriage: log rate, motion profile, tank."""

    rate_hz: float = 100.0
    accel_mps2: float = 0.25
    tank_length_m: float = 4.0
    usable_length_m: float = 3.0
    max_steady_s: float = 12.0
    rest_before_s: float = 1.0
    rest_after_s: float = 1.0
    encoder_resolution_m: float = 1e-4


@dataclass(frozen=True)
class BodySettings:
    """The robot body in the towing tank: the paper's drag fits, inertia and centre of pressure."""

    forward_coefficients: tuple[float, float, float] = (9.997, -0.132, 0.334)
    lateral_coefficients: tuple[float, float, float] = (15.571, 0.937, 0.055)
    ramp_speed_mps: float = 0.05
    forward_mass_kg: float = 2.6
    lateral_mass_kg: float = 3.4
    pressure_centre_below_m: float = 0.08
    unsteady_fraction: float = 0.02
    unsteady_corner_hz: float = 1.0
    cross_fraction: float = 0.03


@dataclass(frozen=True)
class TunnelSettings:
    """Everything a tunnel campaign is made from besides the seed, scale, form, truth and effects."""

    loadcell: LoadCellSettings = field(default_factory=LoadCellSettings)
    motion: ControllerSettings = field(default_factory=ControllerSettings)
    clocks: ClockSettings = field(default_factory=ClockSettings)
    physics: Mapping[str, Any] = field(default_factory=dict)
    date: str = "2025-03-14"
    description: str = "virtual water tunnel (workbench virtual lab)"
    max_batch_samples: int = 1_500_000

    def __post_init__(self):
        _check_date(self.date)


@dataclass(frozen=True)
class TowingSettings:
    """Everything a towing-tank campaign is made from besides the seed, scale and form."""

    loadcell: LoadCellSettings = field(default_factory=LoadCellSettings)
    clocks: ClockSettings = field(default_factory=ClockSettings)
    carriage: CarriageSettings = field(default_factory=CarriageSettings)
    body: BodySettings = field(default_factory=BodySettings)
    date: str = "2025-03-20"
    description: str = "virtual towing tank (workbench virtual lab)"

    def __post_init__(self):
        _check_date(self.date)


def _check_date(value: str) -> None:
    try:
        _dt.date.fromisoformat(str(value))
    except ValueError:
        raise SettingError(f"date {value!r} is not YYYY-MM-DD") from None


@dataclass(frozen=True)
class TunnelCampaignSettings:
    """The rest of a ``tunnel`` section: what campaign to make (size, seed, form, truth, planted effects)."""

    scale: str = "demo"
    seed: int = 0
    form: str = "csv"
    truth: str = "rich"
    #: effect specs, ``"servo_lag:tau_s=0.04"`` or mappings (workbench virtual-lab effects)
    effects: tuple[Any, ...] = ()
    flow_speeds_mps: tuple[float, ...] | None = None
    #: "paper", "demo", a mapping of parameter lists or a list of parameter sets (:func:`resolve_grid`)
    grid: Any = None
    cycles: int | None = None
    feedback: bool | None = None
    bin_faults: bool = False


@dataclass(frozen=True)
class TowingCampaignSettings:
    """The rest of a ``towing`` section: what campaign to make."""

    scale: str = "demo"
    seed: int = 0
    form: str = "csv"
    speeds_mps: tuple[float, ...] | None = None
    headings: tuple[str, ...] | None = None
    repeats: int | None = None


def campaign_and_rig(raw: Mapping[str, Any] | None, key: str, path: str | None = None):
    """A ``tunnel`` or ``towing`` section as (campaign settings, rig settings).

    Unknown keys are refused against both halves (a ParamsError naming the file, the key path and
    every allowed key).
    """
    from workbench.params import build, suggest

    campaign_cls, rig_cls = {"tunnel": (TunnelCampaignSettings, TunnelSettings),
                             "towing": (TowingCampaignSettings, TowingSettings)}[key]
    raw = dict(raw or {})
    own = [f.name for f in dataclasses.fields(campaign_cls)]
    allowed = own + [f.name for f in dataclasses.fields(rig_cls)]
    for name in raw:
        if name not in allowed:
            raise ParamsError(f"unknown setting '{name}'", path=path, where=f"{key}.{name}",
                              hint=suggest(str(name), allowed))
    campaign = build(campaign_cls, {k: v for k, v in raw.items() if k in own}, key=key, path=path)
    rig = build(rig_cls, {k: v for k, v in raw.items() if k not in own}, key=key, path=path)
    return campaign, rig


def tunnel_settings(raw: Mapping[str, Any] | None = None, where: str = "tunnel") -> TunnelSettings:
    """TunnelSettings from a YAML section's rig part (other keys are the caller's); see workbench.params."""
    from workbench.params import build

    return build(TunnelSettings, raw, key=where)


def towing_settings(raw: Mapping[str, Any] | None = None, where: str = "towing") -> TowingSettings:
    """TowingSettings from a YAML section's rig part; see workbench.params."""
    from workbench.params import build

    return build(TowingSettings, raw, key=where)


def settings_json(s) -> dict:
    """Settings as plain JSON (for truth.json)."""
    return dataclasses.asdict(s)
