"""One run from raw files to processed rows: read, check, align clocks, filter, resample, differentiate.

Order of operations (docs/ingest.md):

1. read the run's files (CSV, .bin or MCAP) and check each stream (timestamps, gaps, NaNs);
2. fit the load cell's clock to the controller's from paired rising trigger edges;
3. put the load cell on a uniform grid of its own clock (bridging dropped frames), low-pass it
   with the zero-phase filter (this is also the anti-aliasing filter before the resample);
4. map that grid onto the controller clock and interpolate onto the controller's ticks;
5. joint angular velocities (tunnel) or carriage speed (towing) by a Savitzky-Golay derivative;
6. ``time_s`` = controller time minus the run's first rising edge; the pre-run rest stretch
   (``time_s < 0``) is kept, up to ``max_rest_s``, when the leg was still during it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import polars as pl

from workbench.contract.campaign import Campaign, RunSpec
from workbench.contract.columns import TUNNEL_MOTION_PARAMS, WRENCH_CHANNELS
from workbench.errors import DataError
from workbench.ingest.clock import align_clock
from workbench.ingest.params import IngestSettings
from workbench.ingest.readers import read_run
from workbench.ingest.schema import columns_for
from workbench.ingest.streams import Stream, check_stream
from workbench.signals.filters import (
    derivative,
    is_uniform,
    lowpass,
    lowpass_sampled,
    resample_linear,
    uniform_grid,
)


@dataclass
class RunOutput:
    """A processed run: per-tick columns, per-run constants, its quality record, its raw files' hashes.

    Kept as numpy arrays; :func:`assemble` makes one frame of many runs at once.
    """

    run_id: str
    facility: str
    columns: dict[str, np.ndarray]
    constants: dict[str, object]
    quality: dict
    hashes: dict[str, str] = field(default_factory=dict)

    @property
    def frame(self) -> pl.DataFrame:
        """This run's rows (contract section 3)."""
        return assemble([self], self.facility)


#: polars types of the per-run constant columns
_CONSTANT_TYPES = {"campaign_id": pl.String, "run_id": pl.String, "heading": pl.String, "interpolated": pl.Boolean,
                   "cycles": pl.Int32}


def assemble(outputs: list[RunOutput], facility: str) -> pl.DataFrame:
    """One frame from many runs: per-tick arrays concatenated, constants repeated per tick."""
    names = columns_for(facility)
    if not outputs:
        return pl.DataFrame(schema={c: _CONSTANT_TYPES.get(c, pl.Float64) for c in names})
    counts = np.array([len(o.columns["time_s"]) for o in outputs])
    which = np.repeat(np.arange(len(outputs)), counts)
    cols = {}
    for c in names:
        if c in outputs[0].columns:
            cols[c] = pl.Series(c, np.concatenate([o.columns[c] for o in outputs]))
        else:
            per_run = pl.Series(c, [o.constants[c] for o in outputs], dtype=_CONSTANT_TYPES.get(c, pl.Float64))
            cols[c] = per_run.gather(which)
    return pl.DataFrame(cols)


def angle_source(campaign: Campaign) -> str:
    """``measured`` when the motion logs carry measured angles ([motion] feedback), else ``commanded``."""
    return "measured" if campaign.motion is not None and campaign.motion.feedback else "commanded"


def process_run(campaign: Campaign, run: RunSpec, params: IngestSettings) -> RunOutput:
    """Turn one run's raw files into processed rows on the controller's ticks."""
    streams = read_run(campaign, run)
    streams = {role: check_stream(s, params, run.id, campaign.loadcell.full_scale) for role, s in streams.items()}
    lc = streams["loadcell"]
    ctrl = streams["motion" if campaign.is_tunnel else "carriage"]
    fit = align_clock(ctrl.time_s, ctrl.sync, lc.time_s, lc.sync, path=lc.path, run=run.id,
                      max_residual_ms=params.max_edge_residual_ms)

    # load cell: uniform grid on its own clock -> zero-phase low-pass -> controller ticks
    saturated = _saturation(lc.values, campaign.loadcell.full_scale, params.saturation_fraction)
    grid, w = _filtered_loadcell(lc, params)
    grid_c = fit.to_controller(grid)

    tc = ctrl.time_s
    t_rel = tc - fit.start_s
    keep = (tc >= grid_c[0]) & (tc <= grid_c[-1]) & (t_rel >= -params.max_rest_s)
    if campaign.is_tunnel:
        cols, keep, flags = _joint_columns(ctrl, campaign, params, keep, t_rel)
    else:
        cols, flags = _carriage_columns(ctrl, params), []
    if not (keep & (t_rel >= 0)).any():
        raise DataError("the load-cell log does not overlap the run on the controller clock", path=lc.path,
                        run=run.id)
    data: dict[str, np.ndarray] = {"time_s": t_rel[keep]}
    for name, x in cols.items():
        data[name] = x[keep]
    wt = resample_linear(grid_c, w, tc[keep])
    for k, c in enumerate(WRENCH_CHANNELS):
        data[c] = wt[:, k]

    duration = float(t_rel[keep][-1])
    nan_filled = sum(s.nan_filled for s in streams.values())
    flags += _quality_flags(campaign, run, duration, tc, lc, nan_filled, saturated)
    quality = _quality(run, lc, ctrl, fit, saturated, nan_filled, t_rel[keep], flags)
    hashes = {_rel(campaign, s): s.sha256 for s in streams.values()}
    return RunOutput(run_id=run.id, facility=campaign.facility, columns=data, constants=_constants(campaign, run),
                     quality=quality, hashes=hashes)


def _filtered_loadcell(lc: Stream, params: IngestSettings) -> tuple[np.ndarray, np.ndarray]:
    """The load cell's wrench on a uniform grid of its own clock (dropped frames bridged), zero-phase low-passed."""
    raw = lc.column_matrix(WRENCH_CHANNELS)
    if is_uniform(lc.time_s, 0.05):
        grid, w = lc.time_s, raw
        dt = (grid[-1] - grid[0]) / (len(grid) - 1)
    else:
        grid, dt = uniform_grid(lc.time_s)
        w = resample_linear(lc.time_s, raw, grid)
    return grid, lowpass(w, 1.0 / dt, params.lowpass_cutoff_hz, params.lowpass_order)


def _joint_columns(ctrl: Stream, campaign: Campaign, params: IngestSettings, keep: np.ndarray, t_rel: np.ndarray
                   ) -> tuple[dict[str, np.ndarray], np.ndarray, list[str]]:
    """Joint angles and velocities on the controller ticks; the rows kept (the rest dropped when the leg moved)."""
    th, tk = _angles(ctrl, campaign, params)
    oh = derivative(ctrl.time_s, th, params.velocity_window_ticks, params.velocity_polyorder)
    ok_ = derivative(ctrl.time_s, tk, params.velocity_window_ticks, params.velocity_polyorder)
    flags = []
    rest = keep & (t_rel < 0)
    if rest.any() and max(np.ptp(th[rest]), np.ptp(tk[rest])) > params.rest_tolerance_deg:
        keep = keep & (t_rel >= 0)
        flags.append("moving_before_start")
    return dict(theta_h_deg=th, theta_k_deg=tk, omega_h_dps=oh, omega_k_dps=ok_), keep, flags


def _carriage_columns(ctrl: Stream, params: IngestSettings) -> dict[str, np.ndarray]:
    """The carriage's low-passed position and its speed on the controller ticks."""
    pos = lowpass_sampled(ctrl.time_s, ctrl.values["position_m"], params.lowpass_cutoff_hz, params.lowpass_order)
    speed = derivative(ctrl.time_s, pos, params.velocity_window_ticks, params.velocity_polyorder)
    return dict(position_m=pos, speed_mps=speed)


def _constants(campaign: Campaign, run: RunSpec) -> dict[str, object]:
    """The run's per-run columns: ids, flow speed, and the motion parameters (tunnel) or the heading (towing)."""
    constants: dict[str, object] = {"campaign_id": campaign.id, "run_id": run.id,
                                    "flow_speed_mps": float(run.flow_speed_mps), "interpolated": False}
    if campaign.is_tunnel:
        constants.update({p: float(run.params[p]) for p in TUNNEL_MOTION_PARAMS})
        constants["cycles"] = run.cycles
    else:
        constants["heading"] = run.heading
    return constants


def _quality_flags(campaign: Campaign, run: RunSpec, duration: float, tc: np.ndarray, lc: Stream, nan_filled: int,
                   saturated: dict[str, int]) -> list[str]:
    """The run's quality flags after the rest check: incomplete, dropped_frames, nan_filled, saturated."""
    flags = []
    if campaign.is_tunnel and run.cycles and run.params.get("frequency_hz"):
        expected = run.cycles / run.params["frequency_hz"]
        if duration < expected - 2 * float(np.median(np.diff(tc))):
            flags.append("incomplete")
    if lc.dropped_frames:
        flags.append("dropped_frames")
    if nan_filled:
        flags.append("nan_filled")
    if saturated:
        flags.append("saturated")
    return flags


def _quality(run: RunSpec, lc: Stream, ctrl: Stream, fit, saturated: dict[str, int], nan_filled: int,
             time_s: np.ndarray, flags: list[str]) -> dict:
    """The run's quality record (contract section 3): sources, sample counts, clock fit, faults bridged, flags."""
    rest_s = float(-time_s[0]) if time_s[0] < 0 else 0.0
    return {
        "run_id": run.id,
        "status": "ok",
        "source": "mcap" if run.mcap else lc.source,
        "ticks": len(time_s),
        "loadcell_samples": len(lc),
        "controller_samples": len(ctrl),
        "dropped_frames": int(lc.dropped_frames),
        "dropped_bytes": int(lc.dropped_bytes),
        "clock_offset_ms": round(fit.offset_s * 1e3, 6),
        "clock_drift_ppm": round(fit.drift * 1e6, 4),
        "edges_paired": fit.n_edges,
        "clock_fit": fit.method,
        "edge_residual_max_ms": round(fit.residual_max_s * 1e3, 4),
        "saturated": bool(saturated),
        "saturated_samples": saturated,
        "nan_filled": int(nan_filled),
        "rest_s": round(rest_s, 6),
        "duration_s": round(float(time_s[-1]), 6),
        "flags": flags,
    }


def _rel(campaign: Campaign, s: Stream) -> str:
    try:
        return s.path.relative_to(campaign.root).as_posix()
    except ValueError:
        return s.path.as_posix()


def _angles(ctrl: Stream, campaign: Campaign, params: IngestSettings) -> tuple[np.ndarray, ...]:
    """Joint angles on the controller ticks: measured ones (low-passed like the forces) or commanded."""
    if angle_source(campaign) == "measured":
        return tuple(lowpass_sampled(ctrl.time_s, ctrl.values[c], params.lowpass_cutoff_hz, params.lowpass_order)
                     for c in ("hfe_meas_deg", "kfe_meas_deg"))
    return ctrl.values["hfe_cmd_deg"], ctrl.values["kfe_cmd_deg"]


def _saturation(values: dict[str, np.ndarray], full_scale, fraction: float) -> dict[str, int]:
    """Samples per channel at or beyond ``fraction`` of full scale (flagged, not refused)."""
    if not full_scale:
        return {}
    out = {}
    for c, fs in zip(WRENCH_CHANNELS, full_scale, strict=True):
        x, limit = values[c], fraction * fs
        if x.max() >= limit or x.min() <= -limit:
            out[c] = int((np.abs(x) >= limit).sum())
    return out
