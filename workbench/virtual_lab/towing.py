"""The virtual towing tank: the robot's body towed forward (+y) or sideways (+x) at constant speeds.

Each run: the carriage rests, accelerates at ``accel_mps2``, tows at the run's speed for as long
as the tank allows (capped at ``max_steady_s``), decelerates and rests. The load cell reads the
hydrodynamic force on the robot in the robot's frame, drag opposing the tow:

    F_tow = -(D(v) + m_eff a),   D(v) = (c2 v^2 + c1 v + c0) min(1, v / v_ramp)^2

with the paper's fits (forward 9.997 v^2 - 0.132 v + 0.334, lateral 15.571 v^2 + 0.937 v + 0.055,
N) and a ramp below ``v_ramp`` so the drag vanishes at rest (the fits' constant term is not
physical at v = 0); ``m_eff`` is the robot's mass plus added mass along the tow. Coloured
fluctuations (a few % of D) ride on the tow axis and, smaller, on the cross axes; the drag acts
below the load cell, so it also shows as a torque. Forward tows read on fy (negative), lateral on
fx. The rig (clocks, trigger line, load-cell errors, forms) is the tunnel's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
from scipy import signal

from workbench.atomic import atomic_dir
from workbench.contract.columns import TRIGGER_HIGH_S
from workbench.errors import ParamsError
from workbench.virtual_lab import rig, writers
from workbench.virtual_lab.settings import FORMS, SCALES, TowingSettings, settings_json, towing_settings
from workbench.virtual_lab.tunnel import maybe_progress

HEADINGS = ("forward", "lateral")
_RUN_FORMS = ("csv", "bin", "mcap")


@dataclass(frozen=True)
class TowPlan:
    """One towing run."""

    index: int
    id: str
    speed_mps: float
    heading: str
    form: str


@dataclass(frozen=True)
class TowProfile:
    """Trapezoidal speed profile of the carriage from its start (controller time ``start_s``)."""

    start_s: float
    speed_mps: float
    accel_mps2: float
    steady_s: float

    @property
    def ramp_s(self) -> float:
        """Duration of acceleration (= deceleration)."""
        return self.speed_mps / self.accel_mps2

    @property
    def duration_s(self) -> float:
        """Start of acceleration to end of deceleration."""
        return 2 * self.ramp_s + self.steady_s

    def phases(self) -> dict[str, float]:
        """Controller times of the phase boundaries."""
        t0 = self.start_s
        return {"accel_start_s": t0, "steady_start_s": t0 + self.ramp_s,
                "steady_end_s": t0 + self.ramp_s + self.steady_s, "decel_end_s": t0 + self.duration_s}

    def kinematics(self, t_ctrl: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position (m), speed (m/s) and acceleration (m/s^2) at controller times."""
        v, a, r, s = self.speed_mps, self.accel_mps2, self.ramp_s, self.steady_s
        tau = np.clip(np.asarray(t_ctrl, float) - self.start_s, 0.0, self.duration_s)
        t2 = tau - r - s  # time into the deceleration
        x_ramp = 0.5 * a * r * r
        pos = np.where(tau < r, 0.5 * a * tau**2,
                       np.where(tau < r + s, x_ramp + v * (tau - r),
                                x_ramp + v * s + v * t2 - 0.5 * a * t2**2))
        vel = np.where(tau < r, a * tau, np.where(tau < r + s, v, v - a * t2))
        raw = np.asarray(t_ctrl, float) - self.start_s
        acc = np.where((raw > 0) & (raw < r), a, np.where((raw > r + s) & (raw < self.duration_s), -a, 0.0))
        return pos, np.maximum(vel, 0.0), acc


def drag_n(coefficients: Sequence[float], speed_mps, ramp_mps: float) -> np.ndarray:
    """The body drag D(v) (N, >= 0): the quadratic fit, ramped to zero below ``ramp_mps``."""
    c2, c1, c0 = coefficients
    v = np.abs(np.asarray(speed_mps, float))
    ramp = np.minimum(1.0, v / ramp_mps) ** 2 if ramp_mps > 0 else 1.0
    return (c2 * v * v + c1 * v + c0) * ramp


def _settings(settings) -> TowingSettings:
    if settings is None:
        return TowingSettings()
    if isinstance(settings, TowingSettings):
        return settings
    return towing_settings(settings)


def plan_tows(speeds: Sequence[float], headings: Sequence[str], repeats: int, form: str) -> list[TowPlan]:
    """Each heading, each speed, ``repeats`` times (heading-major), ids r0001, ..."""
    plans = []
    for h in headings:
        for v in speeds:
            for _ in range(repeats):
                i = len(plans)
                f = _RUN_FORMS[i % 3] if form == "mixed" else form
                plans.append(TowPlan(i, f"r{i + 1:04d}", float(v), h, f))
    return plans


def generate_towing(out_dir: str | Path, *, scale: str = "demo", seed: int = 0, form: str = "csv",
                    campaign_id: str | None = None, speeds: Sequence[float] | None = None,
                    headings: Sequence[str] = HEADINGS, repeats: int | None = None,
                    settings: TowingSettings | Mapping | None = None, show_progress: bool = False) -> Path:
    """Write a towing-tank campaign folder (data contract v1) plus truth.json; returns the folder.

    ``scale``: "demo" (8 speeds in 0.05-0.35 m/s x 2 headings) or "paper" (0.1-0.35 m/s every
    0.025 m/s x 2 headings x 3 repeats); ``speeds``/``repeats`` override it.
    """
    out_dir = Path(out_dir)
    if scale not in SCALES:
        raise ParamsError(f"unknown scale {scale!r}", hint=f"one of {', '.join(SCALES)}")
    if form not in FORMS:
        raise ParamsError(f"unknown form {form!r}", hint=f"one of {', '.join(FORMS)}")
    bad = [h for h in headings if h not in HEADINGS]
    if bad or not headings:
        raise ParamsError(f"unknown heading(s) {bad}", hint=f"use {', '.join(HEADINGS)}")
    s = _settings(settings)
    cid = writers.check_target(out_dir, campaign_id)
    sc = SCALES[scale]
    speeds = tuple(float(v) for v in (sc.towing_speeds_mps if speeds is None else speeds))
    if not speeds or any(not math.isfinite(v) or v <= 0 for v in speeds):
        raise ParamsError(f"towing speeds must be positive numbers, got {speeds}")
    plans = plan_tows(speeds, headings, sc.towing_repeats if repeats is None else int(repeats), form)
    calibration = rig.calibration_matrix(s.loadcell)
    records: dict[str, dict] = {}
    with atomic_dir(out_dir) as tmp, maybe_progress(show_progress, f"virtual towing tank {cid}", len(plans)) as bar:
        for p in plans:
            records[p.id] = _run(p, s, seed, tmp, calibration)
            bar.advance(1)
        _write_manifest(tmp, cid, plans, s, calibration)
        writers.write_json(tmp / "truth.json", {
            "generator": writers.GENERATOR, "kind": "towing_tank", "campaign_id": cid, "seed": int(seed),
            "scale": scale, "form": form,
            "drag_model": "F_tow = -(D(v) + m_eff a), D = (c2 v^2 + c1 v + c0) min(1, v / ramp_speed_mps)^2",
            "forward_coefficients": list(s.body.forward_coefficients),
            "lateral_coefficients": list(s.body.lateral_coefficients),
            "clock_model": "daq_time_s = daq_offset_s + (1 + daq_drift_ppm * 1e-6) * controller_time_s",
            "loadcell_model": "reading = wrench + bias + drift_per_s * (daq_time_s - first_daq_time_s) + noise",
            "settings": settings_json(s), "runs": records,
        })
    return out_dir


def _coloured(rng: np.random.Generator, n: int, corner_hz: float, dt: float) -> np.ndarray:
    """Unit-RMS coloured noise (white through a first-order low-pass)."""
    a = math.exp(-2 * math.pi * corner_hz * dt)
    x = signal.lfilter([1 - a], [1.0, -a], rng.standard_normal(n),
                       zi=[a * rng.standard_normal() * math.sqrt((1 - a) / (1 + a))])[0]
    return x / math.sqrt((1 - a) / (1 + a))


def _run(p: TowPlan, s: TowingSettings, seed: int, root: Path, calibration: np.ndarray) -> dict:
    c, b, lc = s.carriage, s.body, s.loadcell
    r = rig.run_rng(seed, p.index, "clock")
    clock = rig.draw_clock(r, s.clocks)
    t0 = float(r.uniform(*s.clocks.controller_origin_s))
    margins = (float(r.uniform(*lc.start_margin_s)), float(r.uniform(*lc.end_margin_s)))
    ramp_len = p.speed_mps**2 / c.accel_mps2
    if ramp_len >= c.usable_length_m:
        raise ParamsError(f"run {p.id}: {p.speed_mps} m/s cannot be reached and stopped within "
                             f"{c.usable_length_m} m at {c.accel_mps2} m/s^2", hint="lower the speed or raise accel_mps2")
    steady = min(c.max_steady_s, (c.usable_length_m - ramp_len) / p.speed_mps)
    duration = 2 * p.speed_mps / c.accel_mps2 + steady
    log = rig.controller_log(t0, c.rate_hz, c.rest_before_s, duration, c.rest_after_s)
    prof = TowProfile(log.start_s, p.speed_mps, c.accel_mps2, steady)
    t_daq, t_ctrl = rig.capture_times(log.times_s[0], log.last_s, clock, lc.rate_hz, margins)
    _, vel, acc = prof.kinematics(t_ctrl)
    forward = p.heading == "forward"
    coeffs = b.forward_coefficients if forward else b.lateral_coefficients
    mass = b.forward_mass_kg if forward else b.lateral_mass_kg
    drag = drag_n(coeffs, vel, b.ramp_speed_mps)
    brng = rig.run_rng(seed, p.index, "body")
    dt = 1.0 / lc.rate_hz
    n = len(t_ctrl)
    fluct = drag * b.unsteady_fraction * _coloured(brng, n, b.unsteady_corner_hz, dt)
    cross = drag * b.cross_fraction * _coloured(brng, n, b.unsteady_corner_hz, dt)
    lift = drag * b.cross_fraction * _coloured(brng, n, b.unsteady_corner_hz, dt)
    tow = -(drag + mass * acc + fluct)
    force = np.zeros((n, 3))
    along, side = (1, 0) if forward else (0, 1)  # forward tows along +y, lateral along +x
    force[:, along] = tow
    force[:, side] = cross
    force[:, 2] = lift
    arm = np.array([0.0, 0.0, -b.pressure_centre_below_m])  # the body's centre of pressure below the cell
    wrench = np.concatenate([force, np.cross(arm, force)], axis=1)
    lrng = rig.run_rng(seed, p.index, "loadcell")
    errors = rig.draw_loadcell_errors(lrng, lc)
    reading = rig.read_loadcell(wrench, t_daq, errors, lc, lrng)
    sync_lc = rig.trigger_level(t_ctrl, log.edges_s, TRIGGER_HIGH_S)
    ticks = log.times_s
    pos_tick, _, _ = prof.kinematics(ticks)
    q = c.encoder_resolution_m
    pos_tick = np.round(pos_tick / q) * q if q > 0 else pos_tick
    carriage_cols = writers.carriage_columns(ticks, pos_tick, rig.trigger_level(ticks, log.edges_s, TRIGGER_HIGH_S))
    lc_cols = writers.loadcell_columns(t_daq, reading, sync_lc)
    files, record = writers.write_run(
        root, p.id, p.form, recorder=(seed, p.index, s.date), latency_s=s.clocks.recorder_latency_s,
        loadcell=(lc_cols, t_ctrl), partner=("carriage", carriage_cols, ticks), t0_s=log.t0_s,
        mcap_streams=writers.mcap_towing_streams,
        write_loadcell_bin=lambda path: writers.write_bin(path, t_daq, reading, sync_lc, calibration))
    record.update({
        "form": p.form, "files": files, "heading": p.heading, "speed_mps": p.speed_mps,
        "steady_drag_n": float(drag_n(coeffs, p.speed_mps, b.ramp_speed_mps)),
        "channel": "fy_n" if forward else "fx_n", "effective_mass_kg": mass,
        "phases": prof.phases(),
        "controller": {"t0_s": log.t0_s, "rate_hz": log.rate_hz, "n_ticks": log.n_ticks,
                       "start_tick": log.start_tick, "first_edge_s": log.start_s, "end_s": log.end_s,
                       "edges": len(log.edges_s)},
        "daq": {"offset_s": clock.offset_s, "drift_ppm": clock.drift_ppm, "rate_hz": lc.rate_hz,
                "first_sample_s": float(t_daq[0]), "samples": int(n),
                "first_edge_daq_s": float(clock.to_daq(log.start_s)), "margins_s": list(margins)},
        "loadcell": errors.to_json(),
    })
    return record


def _write_manifest(root: Path, cid: str, plans: Sequence[TowPlan], s: TowingSettings, calibration) -> None:
    loadcell = writers.loadcell_table(s.loadcell, [p.form for p in plans], calibration)
    runs = [{"id": p.id, "flow_speed_mps": p.speed_mps, "heading": p.heading,
             **writers.run_files(p.id, p.form, "carriage")} for p in plans]
    head = {"schema": "workbench/campaign@1", "id": cid, "facility": "towing_tank", "date": s.date,
            "description": s.description}
    (root / "campaign.toml").write_text(writers.manifest_text(head, {"loadcell": loadcell}, runs), encoding="utf-8")

