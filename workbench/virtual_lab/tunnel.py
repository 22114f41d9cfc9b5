"""The virtual water tunnel: prescribed leg motion (paper eq. 3) -> truth -> rig -> a campaign folder.

Per run: the controller's timeline and trigger edges, the DAQ's clock and sample instants
(``rig``), the commanded motion at those instants, motion and flow effects, then the ground
truth (``physics.TrueLegModel``, batched over runs of similar length), force effects, reading
effects, the load cell's bias, drift and noise, and the files of the run's form. Everything
random comes from per-(seed, run, purpose) streams, so a seed gives the same bytes however the
runs are batched.
"""

from __future__ import annotations

import dataclasses
import math
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np

from workbench.atomic import atomic_dir
from workbench.contract.columns import TRIGGER_HIGH_S
from workbench.errors import ParamsError
from workbench.hydro.motion import JointSinusoid, LegMotion
from workbench.virtual_lab import rig, writers
from workbench.virtual_lab.effects import Effect, by_stage, parse_effects
from workbench.virtual_lab.physics import TRUTHS, TrueLegModel, TruthSettings
from workbench.virtual_lab.settings import (
    FLOW_SPEEDS_MPS,
    FORMS,
    SCALES,
    TunnelSettings,
    resolve_grid,
    settings_json,
    tunnel_settings,
)

_RUN_FORMS = ("csv", "bin", "mcap")
_WRAP_S = 2**32 / 1e6  # the .bin device counter wraps at 2^32 microseconds


@dataclass(frozen=True)
class RunPlan:
    """What one tunnel run is: id, flow speed, motion parameters, cycles and file form."""

    index: int
    id: str
    flow_speed_mps: float
    params: Mapping[str, float]
    cycles: int
    form: str

    @property
    def cycles_s(self) -> float:
        """Length of the prescribed cycles on the controller's eased clock."""
        return self.cycles / self.params["frequency_hz"]


@dataclass
class _Run:
    """A run being simulated (arrays on the DAQ's sample instants unless named ``tick``)."""

    plan: RunPlan
    clock: rig.DaqClock
    log: rig.ControllerLog
    t_daq: np.ndarray
    t_ctrl: np.ndarray
    theta: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray
    flow: np.ndarray
    tick_cmd: np.ndarray
    tick_meas: np.ndarray | None
    extra: dict = field(default_factory=dict)


def plan_runs(speeds: Sequence[float], grid: Sequence[Mapping[str, float]], cycles: int, form: str) -> list[RunPlan]:
    """Every grid entry at every flow speed (speed-major), ids r0001, r0002, ..."""
    plans = []
    for u in speeds:
        for p in grid:
            i = len(plans)
            f = _RUN_FORMS[i % 3] if form == "mixed" else form
            plans.append(RunPlan(i, f"r{i + 1:04d}", float(u), dict(p), int(cycles), f))
    return plans


def read_plan(path: str | Path, form: str = "csv") -> tuple[dict, list[RunPlan]]:
    """A planned campaign (``workbench plan-campaign``'s manifest): its head and one RunPlan per run, as given.

    The runs keep their ids, flow speeds, motion parameters and cycles; file entries, if any, are
    ignored (the virtual lab writes its own). A bad manifest is a one-line error naming the run.
    """
    import tomllib

    from workbench.contract.columns import TUNNEL_MOTION_PARAMS, TUNNEL_OPTIONAL_DEFAULTS
    from workbench.errors import ContractError

    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except FileNotFoundError:
        raise ContractError("plan not found", path=path) from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ContractError(f"not a TOML campaign manifest ({exc})", path=path) from None
    if doc.get("schema") != "workbench/campaign@1" or doc.get("facility") != "water_tunnel":
        raise ContractError("not a water-tunnel campaign manifest (schema workbench/campaign@1, facility "
                            "water_tunnel)", path=path)
    runs = doc.get("runs")
    if not isinstance(runs, list) or not runs:
        raise ContractError("the plan has no [[runs]]", path=path)
    plans, seen = [], set()
    for i, r in enumerate(runs):
        rid = r.get("id") if isinstance(r, dict) else None
        if not isinstance(rid, str) or rid in seen:
            raise ContractError(f"run {i + 1}: missing or repeated id {rid!r}", path=path)
        seen.add(rid)
        try:
            params = {k: float(r.get(k, TUNNEL_OPTIONAL_DEFAULTS.get(k)))
                      for k in TUNNEL_MOTION_PARAMS}
            flow, cycles = float(r["flow_speed_mps"]), r["cycles"]
        except (KeyError, TypeError, ValueError) as exc:
            raise ContractError(f"missing or non-numeric field ({exc})", path=path, run=rid) from None
        if not isinstance(cycles, int) or cycles < 1 or not math.isfinite(flow) or flow < 0 \
                or not params["frequency_hz"] > 0 or not all(math.isfinite(v) for v in params.values()):
            raise ContractError("cycles must be a positive integer, flow speed non-negative, frequency positive",
                                path=path, run=rid)
        f = _RUN_FORMS[i % 3] if form == "mixed" else form
        plans.append(RunPlan(i, rid, flow, params, cycles, f))
    return doc, plans


def ease_time(tau: np.ndarray, cycles_s: float, ease_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The controller's eased clock ``s(tau)`` for the motion, with ``ds/dtau`` and ``d2s/dtau2``.

    ``s`` runs from 0 to ``cycles_s`` while ``tau`` runs from 0 to ``cycles_s + ease_s``: its rate
    rises from 0 to 1 over ``ease_s`` (raised cosine), stays 1, and falls back to 0 over the last
    ``ease_s``. Motion that starts and stops this way has no velocity step; ``ease_s = 0`` is
    the bare equation 3 with its steps.
    """
    tau = np.asarray(tau, float)
    if ease_s <= 0:
        inside = (tau >= 0) & (tau <= cycles_s)
        return np.clip(tau, 0.0, cycles_s), inside.astype(float), np.zeros_like(tau)
    total = cycles_s + ease_s
    k = np.pi / ease_s
    up = np.clip(tau, 0.0, ease_s)
    down = np.clip(total - tau, 0.0, ease_s)
    s = np.where(tau <= ease_s, up / 2 - np.sin(k * up) / (2 * k),
                 np.where(tau >= total - ease_s, cycles_s - (down / 2 - np.sin(k * down) / (2 * k)),
                          tau - ease_s / 2))
    rate = np.where(tau <= ease_s, (1 - np.cos(k * up)) / 2,
                    np.where(tau >= total - ease_s, (1 - np.cos(k * down)) / 2, 1.0))
    acc = np.where(tau <= ease_s, k / 2 * np.sin(k * up),
                   np.where(tau >= total - ease_s, -k / 2 * np.sin(k * down), 0.0))
    outside = (tau <= 0) | (tau >= total)
    return s, np.where(outside, 0.0, rate), np.where(outside, 0.0, acc)


def prescribed(js: JointSinusoid, t_ctrl: np.ndarray, start_s: float, cycles_s: float, ease_s: float = 0.0):
    """Paper eq. 3 from the run's start on the eased clock, the leg at rest at the start pose before and after.

    Returns angles, rates and accelerations as ``(T, 2)`` arrays (HFE, KFE; deg, deg/s, deg/s^2).
    """
    s, ds, dds = ease_time(np.asarray(t_ctrl, float) - start_s, cycles_s, ease_s)
    th, tk, wh, wk, ah, ak = js.evaluate(s)
    theta = np.stack([th, tk], axis=1)
    rate = np.stack([wh, wk], axis=1)
    acc = np.stack([ah, ak], axis=1)
    return theta, rate * ds[:, None], acc * (ds**2)[:, None] + rate * dds[:, None]


def truth_model(truth: str, physics: Mapping[str, Any], effects: Iterable[Effect]) -> TrueLegModel:
    """The ground truth with the settings' physics overrides and the planted force effects."""
    from workbench.params import build

    params = build(TruthSettings, physics, key="tunnel.physics")
    model = TrueLegModel(truth, params)
    for e in by_stage(effects, "force"):
        model = model.with_params(**e.force_changes(model.params))
    return model


def _settings(settings) -> TunnelSettings:
    if settings is None:
        return TunnelSettings()
    if isinstance(settings, TunnelSettings):
        return settings
    return tunnel_settings(settings)


def generate_tunnel(out_dir: str | Path, *, scale: str = "demo", seed: int = 0, form: str = "csv",
                    truth: str = "rich", effects: Iterable = (), campaign_id: str | None = None,
                    flow_speeds: Sequence[float] | None = None, grid: Any = None, cycles: int | None = None,
                    feedback: bool | None = None, bin_faults: bool = False,
                    settings: TunnelSettings | Mapping | None = None, show_progress: bool = False,
                    plan: str | Path | None = None) -> Path:
    """Write a water-tunnel campaign folder (data contract v1) plus truth.json; returns the folder.

    ``scale`` picks the default grid and cycles ("demo": 48 sets x 5 cycles per speed,
    "paper": 480 x 10); ``grid`` / ``cycles`` / ``flow_speeds`` override them. ``form``: csv,
    bin, mcap or mixed (all three, run by run). ``truth``: "rich" or "ef". ``effects``: specs
    such as ``"servo_lag:tau_s=0.04"``. ``feedback`` overrides ``[motion] feedback``.
    ``bin_faults``: the first ``.bin`` capture starts mid-frame, holds corrupt and dropped bytes
    and its device counter wraps around (for ingest tests). ``plan``: a planned campaign's manifest
    (``workbench plan-campaign``): exactly its runs (ids, flow speeds, parameters, cycles) are
    measured, and ``scale``, ``grid``, ``cycles`` and ``flow_speeds`` are not used.
    """
    out_dir = Path(out_dir)
    if scale not in SCALES:
        raise ParamsError(f"unknown scale {scale!r}", hint=f"one of {', '.join(SCALES)}")
    if form not in FORMS:
        raise ParamsError(f"unknown form {form!r}", hint=f"one of {', '.join(FORMS)}")
    if truth not in TRUTHS:
        raise ParamsError(f"unknown truth {truth!r}", hint=f"one of {', '.join(TRUTHS)}")
    s = _settings(settings)
    if feedback is not None:
        s = dataclasses.replace(s, motion=dataclasses.replace(s.motion, feedback=bool(feedback)))
    cid = writers.check_target(out_dir, campaign_id)
    sc = SCALES[scale]
    fx = parse_effects(effects)
    model = truth_model(truth, s.physics, fx)
    speeds = tuple(float(u) for u in (FLOW_SPEEDS_MPS if flow_speeds is None else flow_speeds))
    if not speeds or any(not math.isfinite(u) or u < 0 for u in speeds):
        raise ParamsError(f"flow speeds must be non-negative numbers, got {speeds}")
    n_cycles = sc.cycles if cycles is None else int(cycles)
    if n_cycles <= 0:
        raise ParamsError(f"cycles must be positive, got {n_cycles}")
    if plan is not None:
        plan_doc, plans = read_plan(plan, form)
        s = dataclasses.replace(s, description=f"virtual lab measurement of plan {plan_doc.get('id', '?')} "
                                f"({Path(plan).name}, {len(plans)} runs)")
    else:
        plans = plan_runs(speeds, resolve_grid(sc.grid if grid is None else grid), n_cycles, form)
    first_bin = next((p.index for p in plans if p.form == "bin"), None) if bin_faults else None
    calibration = rig.calibration_matrix(s.loadcell)
    runs_truth: dict[str, dict] = {}
    with atomic_dir(out_dir) as tmp, maybe_progress(show_progress, f"virtual tunnel {cid}", len(plans)) as bar:
        for chunk in _chunks(plans, s):
            runs = [_prepare(p, s, fx, seed, wrap=(p.index == first_bin)) for p in chunk]
            wrenches = _physics(model, runs, s.loadcell.rate_hz)
            for run, w in zip(runs, wrenches, strict=True):
                runs_truth[run.plan.id] = _finish(run, w, tmp, s, fx, seed, calibration,
                                                  faults=run.plan.index == first_bin)
            bar.advance(len(chunk))
        runs_truth = {p.id: runs_truth[p.id] for p in plans}
        _write_manifest(tmp, cid, plans, s, calibration)
        writers.write_json(tmp / "truth.json", {
            "generator": writers.GENERATOR, "kind": "water_tunnel", "campaign_id": cid, "seed": int(seed),
            "scale": scale, "form": form, "truth": model.describe(),
            **({"plan": str(plan)} if plan is not None else {}),
            "effects": [e.spec().to_json() for e in fx],
            "clock_model": "daq_time_s = daq_offset_s + (1 + daq_drift_ppm * 1e-6) * controller_time_s",
            "loadcell_model": "reading = wrench + bias + drift_per_s * (daq_time_s - first_daq_time_s) + noise",
            "settings": settings_json(s), "runs": runs_truth,
        })
    return out_dir


class _Quiet:
    """A progress bar that shows nothing."""

    def advance(self, n: float = 1, status: str | None = None) -> None:
        pass


@contextmanager
def maybe_progress(show: bool, description: str, total: int):
    """A progress bar (console.progress) when asked, else nothing."""
    if not show:
        yield _Quiet()
        return
    from workbench.console import progress

    with progress(description, total=total, unit=" runs") as bar:
        yield bar


def _chunks(plans: Sequence[RunPlan], s: TunnelSettings) -> list[list[RunPlan]]:
    """Runs of similar length together, each batch under the sample budget (padding stays small)."""
    rate = s.loadcell.rate_hz
    extra = s.motion.rest_before_s + s.motion.rest_after_s + s.loadcell.start_margin_s[1] + s.loadcell.end_margin_s[1]
    extra += s.motion.ease_s
    est = {p.index: int((p.cycles_s + extra) * rate) + 2 for p in plans}
    order = sorted(plans, key=lambda p: (est[p.index], p.index))
    chunks, cur = [], []
    for p in order:
        if cur and (len(cur) + 1) * est[p.index] > s.max_batch_samples:
            chunks.append(cur)
            cur = []
        cur.append(p)
    if cur:
        chunks.append(cur)
    return chunks


def _prepare(p: RunPlan, s: TunnelSettings, fx: list[Effect], seed: int, wrap: bool) -> _Run:
    """Clocks, timeline, commanded and actual motion and the flow of one run."""
    r = rig.run_rng(seed, p.index, "clock")
    clock = rig.draw_clock(r, s.clocks)
    t0 = float(r.uniform(*s.clocks.controller_origin_s))
    margins = (float(r.uniform(*s.loadcell.start_margin_s)), float(r.uniform(*s.loadcell.end_margin_s)))
    ease = min(s.motion.ease_s, p.cycles_s)
    log = rig.controller_log(t0, s.motion.rate_hz, s.motion.rest_before_s, p.cycles_s + ease, s.motion.rest_after_s)
    if wrap:  # put the device counter's wrap-around in the middle of the run
        clock = dataclasses.replace(clock, offset_s=_WRAP_S - clock.scale * (log.start_s + log.duration_s / 2))
    t_daq, t_ctrl = rig.capture_times(log.times_s[0], log.last_s, clock, s.loadcell.rate_hz, margins)
    js = JointSinusoid.from_params(p.params)
    theta, omega, alpha = prescribed(js, t_ctrl, log.start_s, p.cycles_s, ease)
    dt = float(np.median(np.diff(t_ctrl)))
    for e in by_stage(fx, "motion"):
        theta, omega, alpha = e.apply_motion(theta, omega, alpha, dt)
    flow = np.full(len(t_ctrl), p.flow_speed_mps)
    frng = rig.run_rng(seed, p.index, "flow")
    for e in by_stage(fx, "flow"):
        flow = e.apply_flow(flow, t_ctrl, frng)
    tick_cmd, _, _ = prescribed(js, log.times_s, log.start_s, p.cycles_s, ease)
    tick_meas = None
    if s.motion.feedback:
        actual = np.stack([np.interp(log.times_s, t_ctrl, theta[:, j]) for j in range(2)], axis=1)
        tick_meas = rig.feedback_angles(actual, rig.run_rng(seed, p.index, "feedback"), s.motion)
    return _Run(p, clock, log, t_daq, t_ctrl, theta, omega, alpha, flow, tick_cmd, tick_meas,
                extra={"margins_s": margins})


def _physics(model: TrueLegModel, runs: list[_Run], rate_hz: float) -> list[np.ndarray]:
    """The truth's wrench for each run, computed as one batch padded with rest at the end."""
    n = max(len(r.t_ctrl) for r in runs)

    def pad(x: np.ndarray, rest: bool) -> np.ndarray:
        if len(x) == n:
            return x
        tail = np.repeat(x[-1:], n - len(x), axis=0) if rest else np.zeros((n - len(x),) + x.shape[1:])
        return np.concatenate([x, tail], axis=0)

    th = np.stack([pad(r.theta, True) for r in runs])
    om = np.stack([pad(r.omega, False) for r in runs])
    al = np.stack([pad(r.alpha, False) for r in runs])
    u = np.stack([pad(r.flow, True) for r in runs])
    motion = LegMotion.from_arrays(1.0 / rate_hz, th[..., 0], th[..., 1], om[..., 0], om[..., 1], u,
                                   al[..., 0], al[..., 1])
    w = model.wrench(motion)
    return [w[i, : len(r.t_ctrl)] for i, r in enumerate(runs)]


def _finish(run: _Run, wrench: np.ndarray, root: Path, s: TunnelSettings, fx: list[Effect], seed: int,
            calibration: np.ndarray, faults: bool) -> dict:
    """Reading effects, load-cell errors and noise, the files; returns the run's truth record."""
    p, log, clock = run.plan, run.log, run.clock
    t_since = run.t_ctrl - log.start_s
    dt = float(np.median(np.diff(run.t_ctrl)))
    erng = rig.run_rng(seed, p.index, "effects")
    for e in by_stage(fx, "reading"):
        wrench = e.apply_reading(wrench, t_since, run.t_daq, dt, erng)
    lrng = rig.run_rng(seed, p.index, "loadcell")
    errors = rig.draw_loadcell_errors(lrng, s.loadcell)
    reading = rig.read_loadcell(wrench, run.t_daq, errors, s.loadcell, lrng)
    sync_lc = rig.trigger_level(run.t_ctrl, log.edges_s, TRIGGER_HIGH_S)
    ticks = log.times_s
    sync_tick = rig.trigger_level(ticks, log.edges_s, TRIGGER_HIGH_S)
    measured = None if run.tick_meas is None else (run.tick_meas[:, 0], run.tick_meas[:, 1])
    motion_cols = writers.motion_columns(ticks, run.tick_cmd[:, 0], run.tick_cmd[:, 1], sync_tick, measured)
    lc_cols = writers.loadcell_columns(run.t_daq, reading, sync_lc)
    def write_loadcell_bin(path: Path) -> dict:
        spec = {"mid_frame": True, "corrupt": 3, "drop": 2} if faults else None
        out = writers.write_bin(path, run.t_daq, reading, sync_lc, calibration, spec, rig.run_rng(seed, p.index, "bin"))
        out["counter_wraps"] = bool(np.floor(run.t_daq[0] / _WRAP_S) != np.floor(run.t_daq[-1] / _WRAP_S))
        return out

    files, record = writers.write_run(
        root, p.id, p.form, recorder=(seed, p.index, s.date), latency_s=s.clocks.recorder_latency_s,
        loadcell=(lc_cols, run.t_ctrl), partner=("motion", motion_cols, ticks), t0_s=log.t0_s,
        mcap_streams=writers.mcap_tunnel_streams, write_loadcell_bin=write_loadcell_bin)
    record.update({
        "form": p.form, "files": files, "flow_speed_mps": p.flow_speed_mps, "params": dict(p.params),
        "cycles": p.cycles,
        "controller": {"t0_s": log.t0_s, "rate_hz": log.rate_hz, "n_ticks": log.n_ticks,
                       "start_tick": log.start_tick, "first_edge_s": log.start_s, "end_s": log.end_s,
                       "edges": len(log.edges_s), "ease_s": log.duration_s - p.cycles_s},
        "daq": {"offset_s": clock.offset_s, "drift_ppm": clock.drift_ppm, "rate_hz": s.loadcell.rate_hz,
                "first_sample_s": float(run.t_daq[0]), "samples": int(len(run.t_daq)),
                "first_edge_daq_s": float(clock.to_daq(log.start_s)), "margins_s": list(run.extra["margins_s"])},
        "loadcell": errors.to_json(),
        "flow_rms_mps": float(np.sqrt(np.mean((run.flow - p.flow_speed_mps) ** 2))),
        "wrench_rms": [float(x) for x in np.sqrt(np.mean(wrench[(t_since >= 0) & (t_since <= log.duration_s)] ** 2,
                                                         axis=0))],
    })
    return record


def _write_manifest(root: Path, cid: str, plans: Sequence[RunPlan], s: TunnelSettings, calibration) -> None:
    loadcell = writers.loadcell_table(s.loadcell, [p.form for p in plans], calibration)
    runs = [{"id": p.id, "flow_speed_mps": p.flow_speed_mps, **{k: float(v) for k, v in p.params.items()},
             "cycles": p.cycles, **writers.run_files(p.id, p.form, "motion")} for p in plans]
    head = {"schema": "workbench/campaign@1", "id": cid, "facility": "water_tunnel", "date": s.date,
            "description": s.description}
    text = writers.manifest_text(head, {"loadcell": loadcell,
                                        "motion": {"rate_hz": float(s.motion.rate_hz), "feedback": s.motion.feedback}},
                                 runs)
    (root / "campaign.toml").write_text(text, encoding="utf-8")
