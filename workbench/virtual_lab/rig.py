"""The rig around the physics: controller ticks, the trigger line, the DAQ clock and the load cell.

Physical time is the controller's clock (it runs the motion). The DAQ's clock reads
``daq = offset_s + (1 + drift_ppm 1e-6) * controller`` (per run; any origin, tens to 200 ppm),
its samples are uniform on its own clock, and each sample reads the trigger line into ``sync``.
The controller raises the line on the run's start tick and again every 1.000 s of its own clock
(the first tick at or after each whole second), high for 0.1 s; its log rows are its ticks, so
its ``sync`` rises exactly on the edges (data contract, "The trigger line").
The load cell adds a per-run bias, a slow linear drift (from the capture's start) and white
noise; ``.bin`` captures carry counts that ``calibration @ counts`` turns back into SI.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass

import numpy as np

from workbench.contract.columns import TRIGGER_HIGH_S, TRIGGER_PERIOD_S
from workbench.virtual_lab.settings import ClockSettings, ControllerSettings, LoadCellSettings

_STREAMS = {"clock": 1, "loadcell": 2, "effects": 3, "feedback": 4, "bin": 5, "mcap": 6, "body": 7, "flow": 8}


def run_rng(seed: int, run_index: int, stream: str) -> np.random.Generator:
    """An independent random stream per (seed, run, purpose): results do not depend on batching."""
    return np.random.default_rng([int(seed), int(run_index), _STREAMS[stream]])


@dataclass(frozen=True)
class DaqClock:
    """The DAQ's clock against the controller's: ``daq = offset_s + (1 + drift_ppm 1e-6) controller``."""

    offset_s: float
    drift_ppm: float

    @property
    def scale(self) -> float:
        """1 + drift."""
        return 1.0 + self.drift_ppm * 1e-6

    def to_daq(self, t_ctrl):
        """Controller time -> DAQ time."""
        return self.offset_s + self.scale * np.asarray(t_ctrl, float)

    def to_controller(self, t_daq):
        """DAQ time -> controller time."""
        return (np.asarray(t_daq, float) - self.offset_s) / self.scale


def draw_clock(rng: np.random.Generator, s: ClockSettings) -> DaqClock:
    """Offset uniform in its range, drift magnitude uniform in its range with a random sign."""
    drift = rng.uniform(*s.daq_drift_ppm) * rng.choice([-1.0, 1.0])
    return DaqClock(offset_s=float(rng.uniform(*s.daq_offset_s)), drift_ppm=float(drift))


@dataclass(frozen=True)
class ControllerLog:
    """One run's controller timeline: ticks, the run's start tick, its end, the trigger edges."""

    t0_s: float
    rate_hz: float
    n_ticks: int
    start_tick: int
    duration_s: float
    edges_s: np.ndarray

    @property
    def times_s(self) -> np.ndarray:
        """Tick times on the controller's clock."""
        return self.t0_s + np.arange(self.n_ticks) / self.rate_hz

    @property
    def start_s(self) -> float:
        """The run's start (its first trigger edge)."""
        return self.t0_s + self.start_tick / self.rate_hz

    @property
    def end_s(self) -> float:
        """The end of the prescribed motion."""
        return self.start_s + self.duration_s

    @property
    def last_s(self) -> float:
        """The last tick."""
        return self.t0_s + (self.n_ticks - 1) / self.rate_hz


def controller_log(t0_s: float, rate_hz: float, rest_before_s: float, duration_s: float,
                   rest_after_s: float) -> ControllerLog:
    """Ticks from ``t0_s``: a rest stretch, the run (``duration_s``), a rest stretch; edges every 1.000 s."""
    start = int(round(rest_before_s * rate_hz))
    n_run = int(math.ceil(duration_s * rate_hz - 1e-9))
    n = start + n_run + int(round(rest_after_s * rate_hz)) + 1
    n_edges = int(math.floor(duration_s / TRIGGER_PERIOD_S + 1e-9)) + 1
    ticks = start + np.ceil(np.arange(n_edges) * TRIGGER_PERIOD_S * rate_hz - 1e-9).astype(int)
    edges = t0_s + ticks[ticks < n] / rate_hz
    return ControllerLog(t0_s=float(t0_s), rate_hz=float(rate_hz), n_ticks=n, start_tick=start,
                         duration_s=float(duration_s), edges_s=edges)


def trigger_level(t_ctrl: np.ndarray, edges_s: np.ndarray, high_s: float = TRIGGER_HIGH_S) -> np.ndarray:
    """The line's level (0/1) at controller times: high for ``high_s`` from each rising edge."""
    t = np.asarray(t_ctrl, float)
    idx = np.searchsorted(edges_s, t, side="right") - 1
    last = edges_s[np.clip(idx, 0, len(edges_s) - 1)]
    # a tick sits exactly on its edge: compare with a tolerance far below any sample period
    high = (idx >= 0) & (t - last < high_s - 1e-9)
    return high.astype(np.uint8)


def capture_times(first_ctrl_s: float, last_ctrl_s: float, clock: DaqClock, rate_hz: float,
                  margins_s: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """DAQ sample times (DAQ clock, whole microseconds) spanning the controller log plus margins.

    Returns ``(t_daq, t_ctrl)``; the capture starts ``margins_s[0]`` before the controller's
    first tick and ends ``margins_s[1]`` after its last one.
    """
    d0 = float(clock.to_daq(first_ctrl_s - margins_s[0]))
    d1 = float(clock.to_daq(last_ctrl_s + margins_s[1]))
    n = int(math.floor((d1 - d0) * rate_hz)) + 1
    t_daq = np.round((d0 + np.arange(n) / rate_hz) * 1e6) / 1e6
    return t_daq, clock.to_controller(t_daq)


@dataclass(frozen=True)
class LoadCellErrors:
    """Per-run load-cell errors: bias (6,) and linear drift rate (6,) from the capture's start."""

    bias: np.ndarray
    drift_per_s: np.ndarray

    def to_json(self) -> dict:
        """For truth.json."""
        return {"bias": [float(x) for x in self.bias], "drift_per_s": [float(x) for x in self.drift_per_s]}


def _per_channel(force: float, torque: float) -> np.ndarray:
    return np.array([force] * 3 + [torque] * 3, float)


def draw_loadcell_errors(rng: np.random.Generator, s: LoadCellSettings) -> LoadCellErrors:
    """Gaussian bias and drift rate per channel."""
    bias = rng.standard_normal(6) * _per_channel(s.bias_n, s.bias_nm)
    drift = rng.standard_normal(6) * _per_channel(s.drift_n_per_s, s.drift_nm_per_s)
    return LoadCellErrors(bias=bias, drift_per_s=drift)


def read_loadcell(wrench: np.ndarray, t_daq: np.ndarray, errors: LoadCellErrors, s: LoadCellSettings,
                  rng: np.random.Generator) -> np.ndarray:
    """What the load cell reports (T, 6): wrench + bias + drift + white noise."""
    noise = rng.standard_normal(wrench.shape) * _per_channel(s.noise_n, s.noise_nm)
    return wrench + errors.bias + errors.drift_per_s * (t_daq - t_daq[0])[:, None] + noise


def calibration_matrix(s: LoadCellSettings) -> np.ndarray:
    """``SI = C @ counts``: per-channel resolution with small fixed cross terms (a decoupling matrix)."""
    res = _per_channel(1.0 / s.counts_per_n, 1.0 / s.counts_per_nm)
    i, j = np.meshgrid(np.arange(6), np.arange(6), indexing="ij")
    pattern = ((7 * i + 3 * j) % 5 - 2) / 2.0  # a fixed spread of -1 .. 1
    coupling = np.where(i == j, 1.0, s.calibration_coupling * pattern)
    return res[:, None] * coupling


def feedback_angles(actual_deg: np.ndarray, rng: np.random.Generator, s: ControllerSettings) -> np.ndarray:
    """Measured joint angles: actual + noise, quantised to the feedback resolution."""
    noisy = actual_deg + rng.standard_normal(actual_deg.shape) * s.feedback_noise_deg
    q = s.feedback_resolution_deg
    return np.round(noisy / q) * q if q > 0 else noisy


def recorder_origin_ns(seed: int, run_index: int, date: str = "2025-03-14") -> int:
    """The MCAP recorder's clock (ns since the epoch) at a run's first controller tick.

    Runs are two minutes apart from 09:00 UTC of the campaign date, plus up to a second of
    start-up jitter: a plausible, deterministic wall clock that no alignment may rely on.
    """
    day = _dt.datetime.fromisoformat(date).replace(hour=9, tzinfo=_dt.timezone.utc)
    return (int(day.timestamp()) + 120 * int(run_index)) * 10**9 + int(run_rng(seed, run_index, "mcap").integers(0, 10**9))


def recorder_log_ns(origin_ns: int, t_ctrl: np.ndarray, t0_s: float, rng: np.random.Generator,
                    latency_s: tuple[float, float]) -> np.ndarray:
    """MCAP log times (ns) of one device's messages: arrival = sample time + latency, in order.

    A device's messages arrive in the order it sent them, so the times never decrease.
    """
    arrival = np.asarray(t_ctrl, float) - t0_s + rng.uniform(*latency_s, len(t_ctrl))
    return origin_ns + np.round(np.maximum.accumulate(arrival) * 1e9).astype(np.int64)
