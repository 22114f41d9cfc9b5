"""Plausibility: the rig's ranges, against which manifests and raw cells are checked.

The data contract fixes the shape of a campaign; these limits catch values that have the right
shape but cannot come from the rigs (``cycles = 3000000000``, a flow speed of 1e300 m/s, a load-cell
cell of 1e308 N, ``inf``). The defaults are generous bounds around the lab's water tunnel, towing tank
and leg (docs/campaigns.md, "Plausible values"); a campaign outside them is refused with the run,
the field or column and the line, and what to do. A rig that really goes further overrides them in
``pipelines/ingest.yaml`` (the contract's campaign.toml has no place for them)::

    ingest:
      limits:
        flow_speed_mps_max: 3.0
        force_abs_max_n: 5000.0
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, Mapping

from workbench.errors import ContractError, ParamsError

_HINT = "check campaign.toml; if the rig really goes there, raise ingest.limits.{key} in pipelines/ingest.yaml"


@dataclass(frozen=True)
class Limits:
    """Bounds on manifest values and raw cells (inclusive)."""

    #: flow speed (tunnel) or carriage speed (towing), m/s: the tunnel runs to 0.3, the carriage to 0.35
    flow_speed_mps_max: float = 2.0
    #: leg motion frequency, Hz (the paper's sets run 0.3-1 Hz)
    frequency_hz_max: float = 5.0
    #: |theta_h/k min/max| in the manifest and |angle| cells in motion logs, degrees
    angle_deg_max: float = 360.0
    #: |phi_rad| and |alpha_rad|
    phase_rad_max: float = 2 * math.pi
    #: cycles of one run (the paper: 10)
    cycles_max: int = 10000
    #: a run's length, cycles / frequency, s
    run_duration_s_max: float = 24 * 3600.0
    #: [loadcell] and [motion] rate_hz
    rate_hz_max: float = 100_000.0
    #: |force| and |torque| cells when [loadcell] has no full_scale (N, N m)
    force_abs_max_n: float = 2000.0
    torque_abs_max_nm: float = 200.0
    #: a cell beyond this multiple of [loadcell] full_scale cannot be a reading: the amplifier and ADC
    #: saturate a little above full scale (cells near 1x are flagged "saturated", not refused)
    full_scale_factor: float = 10.0
    #: |position_m| of the carriage (the tank is 4 m long)
    carriage_position_abs_m_max: float = 1000.0

    def __post_init__(self):
        bad = [f.name for f in fields(self) if not (isinstance(getattr(self, f.name), (int, float))
                                                   and math.isfinite(getattr(self, f.name))
                                                   and getattr(self, f.name) > 0)]
        if bad:
            raise ParamsError(f"limits {bad} must be positive finite numbers", where="ingest.limits")

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | None) -> "Limits":
        """From the ``limits`` mapping of the ingest parameters (workbench.params: unknown keys are a ParamsError)."""
        from workbench.params import build

        return build(cls, values, key="ingest.limits")

    def to_dict(self) -> dict[str, Any]:
        """Plain mapping (for reports)."""
        return asdict(self)

    def cell_limit(self, column: str, full_scale: tuple[float, ...] | None) -> float | None:
        """The largest plausible |value| of a raw column (None: no bound)."""
        from workbench.contract.columns import WRENCH_CHANNELS

        if column in WRENCH_CHANNELS:
            if full_scale is not None:
                return full_scale[WRENCH_CHANNELS.index(column)] * self.full_scale_factor
            return self.force_abs_max_n if column.endswith("_n") else self.torque_abs_max_nm
        if column.endswith("_deg"):
            return self.angle_deg_max
        if column == "position_m":
            return self.carriage_position_abs_m_max
        return None


DEFAULT_LIMITS = Limits()


def manifest_faults(campaign, limits: Limits = DEFAULT_LIMITS) -> list[ContractError]:
    """Every implausible value of a parsed campaign's manifest, as errors naming the field (and run)."""
    errors: list[ContractError] = []
    path = campaign.manifest

    def add(fault, key, *, run=None, where=None):
        errors.append(ContractError(fault, path=path, run=run, where=where or f"field {key}",
                                    hint=_HINT.format(key=key)))

    _rig_faults(campaign, limits, add)
    for run in campaign.runs:
        _run_faults(run, limits, add)
    return errors


def _rig_faults(campaign, limits: Limits, add) -> None:
    """The ``[loadcell]`` and ``[motion]`` tables' implausible rates and full scales, through ``add``."""
    lc = campaign.loadcell
    if math.isfinite(lc.rate_hz) and lc.rate_hz > limits.rate_hz_max:
        add(f"rate_hz = {lc.rate_hz:g} is implausible (at most {limits.rate_hz_max:g} Hz)", "rate_hz_max",
            where="[loadcell] rate_hz")
    if lc.full_scale is not None:
        for name, fs in zip(("fx", "fy", "fz", "tx", "ty", "tz"), lc.full_scale, strict=True):
            top = limits.force_abs_max_n if name.startswith("f") else limits.torque_abs_max_nm
            if fs > top:
                key = "force_abs_max_n" if name.startswith("f") else "torque_abs_max_nm"
                add(f"full_scale {name} = {fs:g} is implausible for the rig's load cell (at most {top:g})", key,
                    where="[loadcell] full_scale")
    if campaign.motion is not None and math.isfinite(campaign.motion.rate_hz) \
            and campaign.motion.rate_hz > limits.rate_hz_max:
        add(f"rate_hz = {campaign.motion.rate_hz:g} is implausible (at most {limits.rate_hz_max:g} Hz)",
            "rate_hz_max", where="[motion] rate_hz")


def _run_faults(run, limits: Limits, add) -> None:
    """One run's implausible flow speed, angles, phases, frequency and length, through ``add``."""
    v = run.flow_speed_mps
    if math.isfinite(v) and v > limits.flow_speed_mps_max:
        add(f"flow_speed_mps = {v:g} is implausible (the rig runs 0 to {limits.flow_speed_mps_max:g} m/s)",
            "flow_speed_mps_max", run=run.id, where="field flow_speed_mps")
    p = run.params
    for key in ("theta_h_min_deg", "theta_h_max_deg", "theta_k_min_deg", "theta_k_max_deg"):
        if key in p and abs(p[key]) > limits.angle_deg_max:
            add(f"{key} = {p[key]:g} is implausible (|angle| at most {limits.angle_deg_max:g} deg)",
                "angle_deg_max", run=run.id, where=f"field {key}")
    for key in ("phi_rad", "alpha_rad"):
        if key in p and abs(p[key]) > limits.phase_rad_max:
            add(f"{key} = {p[key]:g} is implausible (|phase| at most {limits.phase_rad_max:.4g} rad)",
                "phase_rad_max", run=run.id, where=f"field {key}")
    f = p.get("frequency_hz")
    if f is not None and f > limits.frequency_hz_max:
        add(f"frequency_hz = {f:g} is implausible (the leg runs at most {limits.frequency_hz_max:g} Hz)",
            "frequency_hz_max", run=run.id, where="field frequency_hz")
    if run.cycles is not None:
        if run.cycles > limits.cycles_max:
            add(f"cycles = {run.cycles} is implausible (at most {limits.cycles_max})", "cycles_max",
                run=run.id, where="field cycles")
        elif f is not None and 0 < f <= limits.frequency_hz_max \
                and run.cycles / f > limits.run_duration_s_max:
            add(f"cycles / frequency_hz = {run.cycles / f:g} s is implausible for one run "
                f"(at most {limits.run_duration_s_max:g} s)", "run_duration_s_max", run=run.id,
                where="field cycles")
