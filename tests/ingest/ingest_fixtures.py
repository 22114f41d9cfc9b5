"""Small contract-conformant campaigns with exactly known ground truth (clock offsets, drift, forces).

``write_campaign(root, runs=[RunPlan(...)])`` writes campaign.toml and each run's files in the
run's form (csv | bin | mcap). Every device clock is planted: the load cell's clock reads
``offset_s + (1 + drift_ppm 1e-6) * controller time``. The controller raises the trigger on its
ticks (first edge at the run start, then every 1.000 s, high for 0.1 s); the load cell samples
the line (zero-order hold). Forces are known functions of time since the run start.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.contract.serial import counts_from_si, encode_frames
from workbench.hydro.motion import JointSinusoid

PARAMS = dict(theta_h_min_deg=10.0, theta_h_max_deg=-100.0, theta_k_min_deg=80.0, theta_k_max_deg=-20.0,
              frequency_hz=0.5, phi_rad=1.0472, alpha_rad=0.0)
CALIBRATION = (np.diag([1e-4, 1e-4, 1e-4, 1e-5, 1e-5, 1e-5]) + 2e-6 * (np.ones((6, 6)) - np.eye(6)))


def wrench_truth(t_run: np.ndarray, flow_speed: float = 0.1, f: float = 0.5) -> np.ndarray:
    """Known wrench (N, N m) as a function of time since the run's start: slow sinusoids + flow-speed terms."""
    t = np.asarray(t_run, float)
    w = 2 * np.pi * f
    base = np.stack([
        0.02 * np.sin(w * t),
        0.30 * np.sin(w * t + 0.3) + 2.0 * flow_speed ** 2,
        0.20 * np.cos(w * t) - 0.5 * flow_speed,
        0.004 * np.sin(2 * w * t),
        0.010 * np.cos(w * t + 1.0),
        0.003 * np.sin(w * t) + 0.01 * flow_speed,
    ], axis=-1)
    return base


@dataclass
class RunPlan:
    """How to write one run; the defaults make a short clean run."""

    id: str
    flow_speed: float = 0.1
    params: dict = field(default_factory=lambda: dict(PARAMS))
    cycles: int = 4
    form: str = "csv"                  # csv | bin | mcap
    offset_s: float = 37.25            # load-cell clock minus controller clock at controller time 0
    drift_ppm: float = 80.0
    ctrl_origin_s: float = 1000.0      # controller clock at its first log row
    rest_s: float = 1.6                # controller log before the run start
    tail_s: float = 0.6                # controller log after the run end
    lc_lead_s: float = 1.2             # load cell starts this long before the controller log
    lc_trail_s: float = 0.4            # and stops this long after it
    ctrl_rate_hz: float = 65.0
    lc_rate_hz: float = 500.0
    noise_n: float = 0.0
    jitter_s: float = 0.0004           # controller tick jitter (std), as real control loops have
    heading: str = "forward"           # towing only
    seed: int = 0

    def truth(self) -> dict:
        t_start = _controller(self)[3]
        return {"offset_ms": (self.offset_s + self.drift_ppm * 1e-6 * t_start) * 1e3, "drift_ppm": self.drift_ppm,
                "start_s": t_start}


def _controller(plan: RunPlan):
    n_rest = int(np.ceil(plan.rest_s * plan.ctrl_rate_hz))
    run_s = plan.cycles / plan.params["frequency_hz"]
    n = n_rest + int(np.ceil((run_s + plan.tail_s) * plan.ctrl_rate_hz))
    k = np.arange(n)
    jitter = np.random.default_rng(plan.seed + 1).normal(0.0, plan.jitter_s, n) if plan.jitter_s else 0.0
    t = plan.ctrl_origin_s + k / plan.ctrl_rate_hz + np.clip(jitter, -0.4 / plan.ctrl_rate_hz, 0.4 / plan.ctrl_rate_hz)
    ticks = (k - n_rest) / plan.ctrl_rate_hz          # the trigger schedule counts ticks
    in_run = (k >= n_rest) & (ticks <= run_s)
    m = np.floor(ticks + 1e-9)
    sync = (in_run & (ticks - m < 0.1 - 1e-9)).astype(int)
    elapsed = t - t[n_rest]                             # commands are computed at the actual tick time
    return t, sync, np.clip(elapsed, 0.0, run_s), t[n_rest]


def _loadcell(plan: RunPlan, t_ctrl: np.ndarray, sync_ctrl: np.ndarray, t_start: float):
    b = 1 + plan.drift_ppm * 1e-6
    dev0 = plan.offset_s + b * (t_ctrl[0] - plan.lc_lead_s)
    dev1 = plan.offset_s + b * (t_ctrl[-1] + plan.lc_trail_s)
    tau = dev0 + np.arange(int((dev1 - dev0) * plan.lc_rate_hz)) / plan.lc_rate_hz
    tc = (tau - plan.offset_s) / b
    idx = np.searchsorted(t_ctrl, tc, side="right") - 1
    sync = np.where(idx >= 0, sync_ctrl[np.clip(idx, 0, None)], 0)
    run_s = plan.cycles / plan.params["frequency_hz"]
    t_run = np.clip(tc - t_start, 0.0, run_s)
    w = wrench_truth(t_run, plan.flow_speed, plan.params["frequency_hz"])
    if plan.noise_n:
        w = w + np.random.default_rng(plan.seed).normal(0, plan.noise_n, w.shape)
    return tau, sync, w


def _write_csv(path: Path, cols: dict) -> None:
    pl.DataFrame(cols).write_csv(path, float_precision=None)


def write_run(root: Path, plan: RunPlan, facility: str, feedback: bool = False) -> dict:
    """Write one run's files; return its manifest entry (without params)."""
    runs = root / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    t, sync, elapsed, t_start = _controller(plan)
    tau, lsync, w = _loadcell(plan, t, sync, t_start)
    if facility == "water_tunnel":
        th, tk, *_ = JointSinusoid.from_params(plan.params).evaluate(elapsed)
        ctrl = {"time_s": t, "hfe_cmd_deg": th, "kfe_cmd_deg": tk, "sync": sync}
        if feedback:
            ctrl["hfe_meas_deg"] = th - 1.0
            ctrl["kfe_meas_deg"] = tk + 1.0
        ctrl_role = "motion"
    else:
        ctrl = {"time_s": t, "position_m": plan.flow_speed * elapsed, "sync": sync}
        ctrl_role = "carriage"
    lc = {"time_s": tau, **{c: w[:, k] for k, c in enumerate(WRENCH_CHANNELS)}, "sync": lsync}
    entry: dict = {}
    if plan.form == "mcap":
        path = runs / f"{plan.id}.mcap"
        write_mcap(path, lc, ctrl, facility)
        entry["mcap"] = f"runs/{plan.id}.mcap"
        return entry
    if plan.form == "bin":
        time_us = np.rint(tau * 1e6).astype(np.int64)
        counts = counts_from_si(w, CALIBRATION)
        (runs / f"{plan.id}.loadcell.bin").write_bytes(encode_frames(time_us, counts, lsync))
        entry["loadcell"] = f"runs/{plan.id}.loadcell.bin"
    else:
        _write_csv(runs / f"{plan.id}.loadcell.csv", lc)
        entry["loadcell"] = f"runs/{plan.id}.loadcell.csv"
    suffix = "motion" if ctrl_role == "motion" else "carriage"
    _write_csv(runs / f"{plan.id}.{suffix}.csv", ctrl)
    entry[ctrl_role] = f"runs/{plan.id}.{suffix}.csv"
    return entry


def write_mcap(path: Path, lc: dict, ctrl: dict, facility: str) -> None:
    from mcap.writer import Writer

    from workbench.ingest.readers.mcap_reader import TOPICS

    role = "motion" if facility == "water_tunnel" else "carriage"
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start()
        ids = {}
        for r in ("loadcell", role):
            topic, schema = TOPICS[r]
            sid = w.register_schema(schema, "jsonschema", b'{"type": "object"}')
            ids[r] = w.register_channel(topic, "json", sid)
        msgs = []
        for r, cols in (("loadcell", lc), (role, ctrl)):
            names = list(cols)
            arr = np.column_stack([np.asarray(cols[c], float) for c in names])
            for i, row in enumerate(arr):
                rec = {c: (int(v) if c == "sync" else float(v)) for c, v in zip(names, row, strict=True)}
                # recorder log time: its own clock, unrelated to the device clocks
                lt = int(5e9 + (cols["time_s"][i] - cols["time_s"][0]) * 1e9) + (7 if r == "loadcell" else 0)
                msgs.append((lt, ids[r], json.dumps(rec).encode()))
        for lt, cid, data in sorted(msgs, key=lambda m: m[0]):
            w.add_message(cid, log_time=lt, publish_time=lt, data=data)
        w.finish()


def _toml_value(v) -> str:
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def write_campaign(root: Path, runs: list[RunPlan], *, facility: str = "water_tunnel", feedback: bool = False,
                   full_scale=(5.0, 5.0, 5.0, 1.0, 1.0, 1.0), campaign_id: str | None = None,
                   schema: str = "workbench/campaign@1", extra_runs: list[dict] | None = None) -> Path:
    """Write a campaign folder; returns it (its name is the campaign id)."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    lines = [f'schema = "{schema}"', f'id = "{campaign_id or root.name}"', f'facility = "{facility}"',
             "date = 2025-03-14", 'description = "test fixture"', "", "[loadcell]", 'model = "DMI D6095XA"',
             "rate_hz = 500.0"]
    if full_scale:
        lines.append(f"full_scale = {_toml_value(list(full_scale))}")
    if any(p.form == "bin" for p in runs):
        lines.append("calibration = [" + ", ".join(_toml_value([float(x) for x in row]) for row in CALIBRATION) + "]")
    if facility == "water_tunnel":
        lines += ["", "[motion]", "rate_hz = 65.0", f"feedback = {_toml_value(feedback)}"]
    for plan in runs:
        entry = write_run(root, plan, facility, feedback)
        lines += ["", "[[runs]]", f'id = "{plan.id}"', f"flow_speed_mps = {plan.flow_speed!r}"]
        if facility == "water_tunnel":
            lines += [f"{k} = {v!r}" for k, v in plan.params.items()] + [f"cycles = {plan.cycles}"]
        else:
            lines.append(f'heading = "{plan.heading}"')
        lines += [f"{k} = {_toml_value(v)}" for k, v in entry.items()]
    for extra in extra_runs or []:
        lines += ["", "[[runs]]"] + [f"{k} = {_toml_value(v)}" for k, v in extra.items()]
    (root / "campaign.toml").write_text("\n".join(lines) + "\n")
    return root


def tree_hash(root: Path) -> str:
    """One hash over every file's relative path, bytes and mode under ``root`` (raw folder untouched?)."""
    h = hashlib.sha256()
    for p in sorted(Path(root).rglob("*")):
        h.update(p.relative_to(root).as_posix().encode())
        if p.is_file():
            h.update(p.read_bytes())
        h.update(oct(p.stat().st_mode).encode())
    return h.hexdigest()


@pytest.fixture
def campaign(tmp_path):
    """A factory: ``campaign(runs, name="c1", **kwargs)`` -> campaign folder under tmp_path/raw."""
    def make(runs: list[RunPlan] | None = None, name: str = "c1", **kwargs) -> Path:
        runs = runs if runs is not None else [RunPlan("r1"), RunPlan("r2", flow_speed=0.2)]
        return write_campaign(tmp_path / "raw" / name, runs, **kwargs)
    return make
