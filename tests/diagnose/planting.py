"""Plant rig effects into a copy of a raw tunnel campaign by editing its CSV files (contract v1, section 1).

Everything here is written from the physics of the rig, independently of the workbench's effect
library (``workbench/diagnose/effects/``) and of the virtual lab's effects: a program outside
the workbench could do the same to a real campaign. Only the data contract is shared.

Each plant is a function ``plant(lc, mo, run) -> None`` that edits, in place,

* ``lc``: the load-cell table (dict of numpy columns ``time_s, fx_n, ..., tz_nm, sync``), with an
  extra column ``t_ctrl`` (the load-cell samples on the leg controller's clock, paired on
  trigger edges) and ``t_run`` (seconds since the run's first trigger edge);
* ``mo``: the motion table (``time_s, hfe_cmd_deg, kfe_cmd_deg, sync``);
* ``run``: the manifest entry (flow speed, motion parameters).

Magnitudes are real rigs' (issue 13): servo lag 20-80 ms, crosstalk 1-5 %, angle-dependent static
loads, flow tones, structural vibration 2-8 Hz, zero drift of a few mN/s.
"""

from __future__ import annotations

import re
import shutil
import tomllib
from pathlib import Path
from typing import Callable

import numpy as np

LC_COLS = ["time_s", "fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm", "sync"]
MO_COLS = ["time_s", "hfe_cmd_deg", "kfe_cmd_deg", "sync"]
CHANNELS = LC_COLS[1:7]


def _read(path: Path) -> dict[str, np.ndarray]:
    import polars as pl

    frame = pl.read_csv(path, infer_schema=False)
    return {h: frame[h].cast(pl.Float64).to_numpy().copy() for h in frame.columns}


def _write(path: Path, table: dict[str, np.ndarray], cols: list[str]) -> None:
    """Six decimals for the readings, the trigger line as an integer: np.savetxt's "%.6f"/"%d" to the byte, faster."""
    import polars as pl

    frame = pl.DataFrame({c: table[c] for c in cols[:-1]}).with_columns(
        pl.Series(cols[-1], np.rint(table[cols[-1]]).astype(np.int64)))
    frame.write_csv(path, float_precision=6)


def rising_edges(t: np.ndarray, sync: np.ndarray) -> np.ndarray:
    """Times of the samples where the trigger line goes 0 -> 1."""
    i = np.flatnonzero((sync[1:] > 0.5) & (sync[:-1] < 0.5)) + 1
    return t[i]


def controller_clock(lc: dict, mo: dict) -> np.ndarray:
    """The load cell's samples on the controller's clock: a line through the paired trigger edges."""
    a = rising_edges(lc["time_s"], lc["sync"])
    b = rising_edges(mo["time_s"], mo["sync"])
    n = min(len(a), len(b))
    slope, icpt = np.polyfit(a[:n], b[:n], 1)
    return slope * lc["time_s"] + icpt


def copy_campaign(src: Path, dst: Path, plants: list[Callable], runs: set[str] | None = None) -> Path:
    """Copy ``src`` to ``dst`` (the campaign id becomes the folder name) and apply ``plants`` to every run."""
    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(src, dst)
    manifest = dst / "campaign.toml"
    text = manifest.read_text()
    text = re.sub(r'^id = ".*"$', f'id = "{dst.name}"', text, count=1, flags=re.M)
    manifest.write_text(text)
    (dst / "truth.json").unlink(missing_ok=True)
    doc = tomllib.loads(text)
    for plant in plants:
        if hasattr(plant, "prepare"):
            plant.prepare(dst, doc)
    for run in doc["runs"]:
        if runs is not None and run["id"] not in runs:
            continue
        lcp, mop = dst / run["loadcell"], dst / run["motion"]
        lc, mo = _read(lcp), _read(mop)
        lc["t_ctrl"] = controller_clock(lc, mo)
        lc["t_run"] = lc["t_ctrl"] - rising_edges(mo["time_s"], mo["sync"])[0]
        for plant in plants:
            plant(lc, mo, run)
        _write(lcp, lc, LC_COLS)
        _write(mop, mo, MO_COLS)
    return dst


# ----------------------------------------------------------------------------- plants
def servo(dead_s: float = 0.0, lag_s: float = 0.0) -> Callable:
    """The servo follows its command after ``dead_s`` and through a first-order lag ``lag_s``.

    The force in the files was made by the motion the leg actually did, x(t). A servo with dead
    time d and lag tau that did x(t) was commanded u with ``x = lag(u(t - d))``, i.e.
    ``u(t) = x(t + d) + tau x'(t + d)``: the commanded angles are rewritten, the forces kept.
    """

    def plant(lc, mo, run):
        t = mo["time_s"]
        for col in ("hfe_cmd_deg", "kfe_cmd_deg"):
            x = mo[col]
            xd = np.interp(t + dead_s, t, x)
            rate = np.gradient(xd, t)
            mo[col] = xd + lag_s * rate

    return plant


def servo_dead_time(dead_s: float) -> Callable:
    """A servo that follows the same command ``dead_s`` later: the leg does x(t - d), so every force does.

    Exact for a pure dead time (the steady flow makes the force a time-invariant functional of
    the motion): the load-cell readings are delayed against the trigger line, the command kept.
    """

    def plant(lc, mo, run):
        t = lc["time_s"]
        for c in CHANNELS:
            lc[c] = np.interp(t - dead_s, t, lc[c])

    return plant


def crosstalk(to: str, src: str, x: float) -> Callable:
    """Load-cell crosstalk: channel ``to`` reads ``x`` times channel ``src`` as well (units as read)."""

    def plant(lc, mo, run):
        lc[to] = lc[to] + x * lc[src]

    return plant


def drift(channel: str, rate_per_s: float) -> Callable:
    """A zero drift of the load cell from the first trigger edge on (thermal drift)."""

    def plant(lc, mo, run):
        lc[channel] = lc[channel] + rate_per_s * np.maximum(lc["t_run"], 0.0)

    return plant


def vibration(freq_hz: float, amp: dict[str, float], seed: int = 0) -> Callable:
    """A narrowband vibration of the rig (a pump, a fan) at a fixed frequency, random phase per run."""
    rng = np.random.default_rng(seed)

    def plant(lc, mo, run):
        ph = rng.uniform(0, 2 * np.pi)
        for c, a in amp.items():
            lc[c] = lc[c] + a * np.sin(2 * np.pi * freq_hz * lc["t_ctrl"] + ph)

    return plant


def mode(f_n_hz: float, zeta: float) -> Callable:
    """A lightly damped mount mode: every reading passes wn^2 / (s^2 + 2 zeta wn s + wn^2)."""
    from scipy import signal

    def plant(lc, mo, run):
        fs = 1.0 / np.median(np.diff(lc["time_s"]))
        wn = 2 * np.pi * f_n_hz
        b, a = signal.bilinear([wn * wn], [1.0, 2 * zeta * wn, wn * wn], fs=fs)
        for c in CHANNELS:
            y = lc[c]
            zi = signal.lfilter_zi(b, a) * y[0]
            lc[c] = signal.lfilter(b, a, y, zi=zi)[0]

    return plant


def hip_weight(torque_nm: float, channel: str = "tx_nm") -> Callable:
    """An angle-dependent static load: a heavy part on the thigh gives ``torque cos(theta_h)`` about the hip."""

    def plant(lc, mo, run):
        th = np.interp(lc["t_ctrl"], mo["time_s"], mo["hfe_cmd_deg"])
        lc[channel] = lc[channel] + torque_nm * np.cos(np.radians(th))

    return plant


class flow_tone:  # noqa: N801 - used like the other plant factories
    """A tone in the tunnel's flow, ``U(t) = U (1 + fraction sin(2 pi f t + phase))``, quasi-steady.

    The force then changes by ``fraction sin(2 pi f t + phase) U dF/dU``. ``dF/dU`` is measured,
    not modelled: the same parameter set is run at several flow speeds, so at each instant of the
    stroke (time since the first trigger edge) a quadratic in U through the readings at every
    speed gives ``dF/dU = b + 2 c U``. Zero-flow runs stay untouched (nothing to modulate).
    """

    def __init__(self, freq_hz: float, fraction: float, seed: int = 0):
        self.freq_hz, self.fraction = freq_hz, fraction
        self.rng = np.random.default_rng(seed)
        self.sens: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def prepare(self, folder: Path, doc: dict) -> None:
        keys = ("theta_h_min_deg", "theta_h_max_deg", "theta_k_min_deg", "theta_k_max_deg", "frequency_hz",
                "phi_rad", "alpha_rad")
        groups: dict[tuple, list] = {}
        for run in doc["runs"]:
            groups.setdefault(tuple(round(float(run.get(k, 0.0)), 4) for k in keys), []).append(run)
        for runs in groups.values():
            if len(runs) < 3:
                continue
            tabs = []
            for run in runs:
                lc, mo = _read(folder / run["loadcell"]), _read(folder / run["motion"])
                t_run = controller_clock(lc, mo) - rising_edges(mo["time_s"], mo["sync"])[0]
                tabs.append((float(run["flow_speed_mps"]), t_run, np.column_stack([lc[c] for c in CHANNELS])))
            t0 = max(t[0] for _, t, _ in tabs)
            t1 = min(t[-1] for _, t, _ in tabs)
            grid = np.arange(t0, t1, 0.002)
            u = np.array([x[0] for x in tabs])
            f = np.stack([np.column_stack([np.interp(grid, t, w[:, j]) for j in range(6)]) for _, t, w in tabs])
            v = np.vander(u, 3)                      # columns U^2, U, 1
            coef = np.linalg.lstsq(v, f.reshape(len(u), -1), rcond=None)[0].reshape(3, len(grid), 6)
            for run, uu in zip(runs, u, strict=True):
                self.sens[run["id"]] = (grid, uu * (2 * coef[0] * uu + coef[1]))   # U dF/dU

    def __call__(self, lc, mo, run):
        if run["id"] not in self.sens or float(run["flow_speed_mps"]) <= 0:
            return
        grid, g = self.sens[run["id"]]
        ph = self.rng.uniform(0, 2 * np.pi)
        s = self.fraction * np.sin(2 * np.pi * self.freq_hz * lc["t_ctrl"] + ph)
        for j, c in enumerate(CHANNELS):
            lc[c] = lc[c] + s * np.interp(lc["t_run"], grid, g[:, j], left=0.0, right=0.0)
