"""Flow-speed interpolation (paper section III-B-2): synthetic runs at speeds between the measured ones.

For each motion parameter set (every manifest motion parameter except the flow speed), the
runs measured at several flow speeds are put on a common phase grid (phase = f t, with t = 0
the run's first trigger edge, where the prescribed motion starts); at every phase point and for
every signal a quadratic in the flow speed is fitted by least squares across the measured
runs (exact with three speeds) and evaluated at the requested speeds. The paper motivates the
quadratic by force growing with the square of the speed. The interpolated forces are then
low-passed with the same zero-phase filter as ingest, and the rows are marked
``interpolated = True`` with run id ``<run>@v<speed>``, ``<run>`` being the parameter set's
lowest-speed measured run.

Only speeds inside the measured range are produced unless ``extrapolate`` is set; a parameter
set with fewer than ``min_speeds`` distinct speeds is left alone (reported, not an error).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np
import polars as pl

from workbench.contract.columns import TUNNEL_MOTION_PARAMS, WRENCH_CHANNELS
from workbench.errors import ContractError
from workbench.signals.filters import lowpass

#: per-tick signals that are interpolated across speeds
SIGNALS = ("theta_h_deg", "theta_k_deg", "omega_h_dps", "omega_k_dps", *WRENCH_CHANNELS)
DEFAULT_SPEEDS = (0.05, 0.15, 0.25)


@dataclass(frozen=True)
class InterpolationSettings:
    """Knobs of the interpolation (section ``interpolate`` of pipelines/ingest.yaml)."""

    speeds_mps: tuple[float, ...] = DEFAULT_SPEEDS
    lowpass_cutoff_hz: float = 6.0
    lowpass_order: int = 4
    min_speeds: int = 3
    extrapolate: bool = False
    #: parameter values closer than this are the same parameter set (manifest floats)
    param_tolerance: float = 1e-6

    @classmethod
    def from_mapping(cls, values: dict[str, Any] | None) -> "InterpolationSettings":
        """From a parameter-file section (workbench.params: unknown keys and wrong types are a ParamsError)."""
        from workbench.params import build

        return build(cls, values, key="interpolate")


#: the name before issue 17 (settings classes end in ``Settings``); kept for existing imports
InterpolationParams = InterpolationSettings


@dataclass
class InterpolationReport:
    """What interpolation did: runs made (with their sources) and parameter sets left alone."""

    made: dict[str, list[str]] = field(default_factory=dict)
    skipped_sets: list[dict[str, Any]] = field(default_factory=list)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (file metadata)."""
        return {"runs_made": len(self.made), "sources": self.made, "skipped_sets": self.skipped_sets}


def interpolate_flow_speeds(frame: pl.DataFrame, speeds: Sequence[float] = DEFAULT_SPEEDS, **kwargs) -> pl.DataFrame:
    """Measured rows plus interpolated rows at ``speeds`` (m/s); see the module docstring."""
    params = InterpolationSettings(speeds_mps=tuple(float(s) for s in speeds), **kwargs)
    return interpolate_with_report(frame, params)[0]


def interpolate_with_report(frame: pl.DataFrame, params: InterpolationSettings) -> tuple[pl.DataFrame, InterpolationReport]:
    """:func:`interpolate_flow_speeds` that also says what it made and what it left alone."""
    missing = [c for c in ("run_id", "time_s", "flow_speed_mps", *SIGNALS, *TUNNEL_MOTION_PARAMS) if c not in frame.columns]
    if missing:
        raise ContractError(f"flow-speed interpolation needs a water-tunnel dataset; missing column(s) {missing}")
    measured = frame.filter(~pl.col("interpolated")) if "interpolated" in frame.columns else \
        frame.with_columns(pl.lit(False).alias("interpolated"))
    report = InterpolationReport()
    keys = ["campaign_id"] if "campaign_id" in measured.columns else []
    digits = max(0, int(round(-np.log10(params.param_tolerance))))
    rounded = [pl.col(p).round(digits).alias(f"__{p}") for p in TUNNEL_MOTION_PARAMS]
    tagged = measured.with_columns(rounded)
    pieces = []
    for _, group in tagged.group_by(keys + [f"__{p}" for p in TUNNEL_MOTION_PARAMS], maintain_order=True):
        group = group.drop([f"__{p}" for p in TUNNEL_MOTION_PARAMS])
        made = _interpolate_set(group, params, report)
        if made is not None:
            pieces.append(made)
    if not pieces:
        return measured, report
    out = pl.concat([measured, *[p.select(measured.columns).cast(measured.schema) for p in pieces]], how="vertical")
    return out, report


def _interpolate_set(group: pl.DataFrame, params: InterpolationSettings, report: InterpolationReport) -> pl.DataFrame | None:
    runs = []
    for (run_id,), g in group.group_by(["run_id"], maintain_order=True):
        g = g.sort("time_s")
        runs.append((str(run_id), float(g["flow_speed_mps"][0]), g["time_s"].to_numpy(),
                     g.select(SIGNALS).to_numpy(), g))
    runs.sort(key=lambda r: (r[1], r[0]))
    speeds = np.array([r[1] for r in runs])
    distinct = np.unique(np.round(speeds, 9))
    first = runs[0][4]
    set_params = {p: float(first[p][0]) for p in TUNNEL_MOTION_PARAMS}
    if len(distinct) < params.min_speeds:
        report.skipped_sets.append({**set_params, "reason": f"{len(distinct)} distinct flow speed(s), "
                                    f"need {params.min_speeds}", "runs": [r[0] for r in runs]})
        return None
    targets = [v for v in params.speeds_mps if np.min(np.abs(distinct - v)) > 1e-9
               and (params.extrapolate or distinct[0] <= v <= distinct[-1])]
    if not targets:
        return None
    # common window, on the grid of the lowest-speed run's ticks; phase = f t aligns the runs
    lo = max(r[2][0] for r in runs)
    hi = min(r[2][-1] for r in runs)
    ref_t = runs[0][2]
    grid = ref_t[(ref_t >= lo) & (ref_t <= hi)]
    if len(grid) < 2:
        report.skipped_sets.append({**set_params, "reason": "runs do not overlap in time", "runs": [r[0] for r in runs]})
        return None
    f = set_params["frequency_hz"]
    phase = f * grid
    y = np.stack([np.stack([np.interp(phase, f * r[2], r[3][:, c]) for c in range(len(SIGNALS))], axis=1)
                  for r in runs])                                        # (runs, ticks, signals)
    design = np.stack([np.ones_like(speeds), speeds, speeds ** 2], axis=1)  # (runs, 3)
    coef, *_ = np.linalg.lstsq(design, y.reshape(len(runs), -1), rcond=None)
    tv = np.asarray(targets, float)
    values = (np.stack([np.ones_like(tv), tv, tv ** 2], axis=1) @ coef).reshape(len(tv), len(grid), len(SIGNALS))
    fs = 1.0 / float(np.median(np.diff(grid)))
    wcols = [SIGNALS.index(c) for c in WRENCH_CHANNELS]
    base = runs[0][0]
    frames = []
    for k, v in enumerate(targets):
        vals = values[k]
        vals[:, wcols] = lowpass(vals[:, wcols], fs, params.lowpass_cutoff_hz, params.lowpass_order)
        run_id = f"{base}@v{v:.3f}"
        report.made[run_id] = [r[0] for r in runs]
        n = len(grid)
        cols: dict[str, Any] = {"run_id": [run_id] * n, "time_s": grid, "flow_speed_mps": np.full(n, v)}
        for i, c in enumerate(SIGNALS):
            cols[c] = vals[:, i]
        cols["interpolated"] = np.ones(n, dtype=bool)
        frame = pl.DataFrame(cols)
        constants = [c for c in first.columns if c not in cols]
        frame = frame.with_columns([pl.lit(first[c][0], dtype=first.schema[c]).alias(c) for c in constants])
        frames.append(frame)
    return pl.concat(frames, how="vertical")
