"""The processed tunnel data as one contiguous array of ticks, indexed into windows by run and tick.

Every tick of every run is one row of a float32 array (``x``: the model inputs, ``y``: the six
wrench channels); runs are contiguous row ranges. A window of ``seq_len`` ticks is named by its
last row, so a split's windows are one int64 array and no window is ever materialised until a
batch is gathered. Windows never cross runs: a window may end at a run's row ``seq_len - 1``
at the earliest.

A run is the ticks sharing (campaign_id, run_id, interpolated) and, for interpolated rows, the
flow speed (interpolation may reuse a measured run's id for each synthetic speed). A parameter
set is the run's motion parameters (contract names, rounded to 1e-6); all flow speeds of a set,
measured or interpolated, share it.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from workbench.contract.columns import TUNNEL_MOTION_PARAMS, TUNNEL_OPTIONAL_DEFAULTS, WRENCH_CHANNELS
from workbench.errors import ContractError, DataError
from workbench.learn.config import FEATURES

#: decimals of the parameter-set key (manifest values are short decimals)
PARAM_DECIMALS = 6
_KEY_COLUMNS = ("campaign_id", "run_id", "interpolated")


@dataclass(frozen=True)
class RunTable:
    """Ticks of many runs in one contiguous store, plus one metadata row per run."""

    #: (N, 5) float32 model inputs in FEATURES order, physical units
    x: np.ndarray
    #: (N, 6) float32 wrench in contract channel order
    y: np.ndarray
    #: (R,) first row of each run
    start: np.ndarray
    #: (R,) ticks per run
    length: np.ndarray
    #: R rows: campaign_id, run_id, interpolated, flow_speed_mps, dt_s, set_key, the motion params
    runs: "object"
    #: motion-parameter columns that define a parameter set
    param_columns: tuple[str, ...]
    #: (N, 6) float32 EF wrench, filled by :func:`with_ef` (for the EF-residual hybrid)
    ef: np.ndarray | None = None

    @property
    def n_runs(self) -> int:
        """Number of runs."""
        return len(self.start)

    def run_slice(self, r: int) -> slice:
        """Rows of run ``r``."""
        return slice(int(self.start[r]), int(self.start[r] + self.length[r]))

    def campaigns(self) -> list[str]:
        """Campaign ids, in order of appearance."""
        return list(dict.fromkeys(self.runs["campaign_id"].to_list()))


def set_key(params: dict, columns: Sequence[str]) -> tuple[float, ...]:
    """The hashable key of a parameter set."""
    return tuple(round(float(params[c]), PARAM_DECIMALS) for c in columns)


def set_label(params: dict) -> str:
    """A short human-readable name of a parameter set (used in JSON and figures)."""
    g = {k: float(v) for k, v in params.items()}
    parts = [f"h{g.get('theta_h_min_deg', 0):g}..{g.get('theta_h_max_deg', 0):g}",
             f"k{g.get('theta_k_min_deg', 0):g}..{g.get('theta_k_max_deg', 0):g}",
             f"f{g.get('frequency_hz', 0):g}", f"phi{g.get('phi_rad', 0):.3g}"]
    if g.get("alpha_rad", 0.0):
        parts.append(f"a{g['alpha_rad']:.3g}")
    return " ".join(parts)


def expand_paths(paths: Sequence[str | Path]) -> list[Path]:
    """Files named, with a folder standing for its ``*.parquet`` files (sorted), e.g. ``datasets/processed/interp``."""
    if not paths:
        raise ContractError("no processed data given", hint="pass --data datasets/processed/<campaign>.parquet")
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found = sorted(p.glob("*.parquet"))
            if not found:
                raise ContractError("no .parquet files in the folder", path=p)
            out += found
        else:
            out.append(p)
    return out


def read_table(paths: Sequence[str | Path]) -> RunTable:
    """Read processed tunnel Parquet files or folders of them (contract section 3) into a :class:`RunTable`.

    Only the needed columns are read, once, straight into float32 arrays: a paper-scale
    campaign (3 M ticks) costs about 130 MB, held once.
    """
    import polars as pl

    files = expand_paths(paths)
    frames = []
    for p in files:
        if not p.is_file():
            raise ContractError("processed data file not found", path=p)
        try:
            schema = pl.read_parquet_schema(p)
        except Exception as exc:  # noqa: BLE001 - any parquet failure is a bad file
            raise ContractError(f"not a readable Parquet file ({type(exc).__name__})", path=p) from exc
        needed = ["campaign_id", "run_id", "time_s", *FEATURES, *WRENCH_CHANNELS,
                  *(c for c in TUNNEL_MOTION_PARAMS if c not in TUNNEL_OPTIONAL_DEFAULTS)]
        missing = [c for c in needed if c not in schema]
        if missing:
            raise ContractError(f"missing columns {', '.join(missing)}",
                                path=p, hint="a water-tunnel processed file per data contract section 3")
        lf = pl.scan_parquet(p)
        extra = [pl.col("interpolated")] if "interpolated" in schema else [pl.lit(False).alias("interpolated")]
        for c, v in TUNNEL_OPTIONAL_DEFAULTS.items():
            if c not in schema:
                extra.append(pl.lit(v).alias(c))
        cols = [pl.col("campaign_id").cast(pl.String), pl.col("run_id").cast(pl.String), pl.col("time_s"),
                *[pl.col(c).cast(pl.Float32) for c in (*FEATURES, *WRENCH_CHANNELS)],
                *[pl.col(c).cast(pl.Float64) for c in TUNNEL_MOTION_PARAMS if c in schema], *extra]
        frames.append(lf.select(cols).with_columns(pl.lit(str(p)).alias("_file")))
    frame = pl.concat(frames, how="diagonal_relaxed").collect()
    return table_from_frame(frame)


def table_from_frame(frame) -> RunTable:
    """Build a :class:`RunTable` from a processed tunnel frame (already in memory)."""
    import polars as pl

    params = tuple(c for c in TUNNEL_MOTION_PARAMS if c in frame.columns)
    if "interpolated" not in frame.columns:
        frame = frame.with_columns(pl.lit(False).alias("interpolated"))
    if "_file" not in frame.columns:
        frame = frame.with_columns(pl.lit("<frame>").alias("_file"))
    speed_key = pl.when(pl.col("interpolated")).then(pl.col("flow_speed_mps").round(6)).otherwise(-1.0)
    frame = (frame.with_columns(speed_key.alias("_speed_key"))
             .sort([*_KEY_COLUMNS, "_speed_key", "time_s"])
             .with_columns(pl.struct([*_KEY_COLUMNS, "_speed_key"]).rle_id().alias("_run")))
    if frame.height == 0:
        raise DataError("no ticks in the processed data")
    meta = (frame.group_by("_run", maintain_order=True)
            .agg(pl.col("campaign_id").first(), pl.col("run_id").first(), pl.col("interpolated").first(),
                 pl.col("flow_speed_mps").first().cast(pl.Float64), pl.col("_file").first(),
                 pl.len().alias("length"), pl.col("time_s").diff().median().alias("dt_s"),
                 pl.col("time_s").diff().min().alias("_min_dt"),
                 *[pl.col(c).first() for c in params], *[pl.col(c).n_unique().alias(f"_nu_{c}") for c in params]))
    for row in meta.filter(pl.col("_min_dt") <= 0).head(1).iter_rows(named=True):
        raise DataError("time_s not strictly increasing within the run", path=row["_file"], run=row["run_id"],
                        hint="duplicate ticks? each run's rows must be unique in time")
    for c in params:
        for row in meta.filter(pl.col(f"_nu_{c}") > 1).head(1).iter_rows(named=True):
            raise DataError(f"{c} changes within the run", path=row["_file"], run=row["run_id"])
    x = np.ascontiguousarray(frame.select(FEATURES).to_numpy(), dtype=np.float32)
    y = np.ascontiguousarray(frame.select(WRENCH_CHANNELS).to_numpy(), dtype=np.float32)
    length = meta["length"].to_numpy().astype(np.int64)
    start = np.concatenate([[0], np.cumsum(length)[:-1]]).astype(np.int64)
    bad = ~(np.isfinite(x).all(axis=1) & np.isfinite(y).all(axis=1))
    if bad.any():
        r = int(np.searchsorted(start, int(np.argmax(bad)), side="right") - 1)
        raise DataError("non-finite inputs or wrench", path=meta["_file"][r], run=meta["run_id"][r],
                        hint="ingest should not leave NaN; re-run ingest")
    keys = [set_key(row, params) for row in meta.select(params).iter_rows(named=True)]
    meta = meta.with_columns(pl.Series("set_key", [list(k) for k in keys]),
                             pl.col("dt_s").fill_null(1.0)).drop(["_run", "_min_dt", *[f"_nu_{c}" for c in params]])
    return RunTable(x=x, y=y, start=start, length=length, runs=meta, param_columns=params)


def motion_of_run(table: RunTable, r: int):
    """Run ``r`` as a one-row :class:`LegMotion` (model input)."""
    from workbench.hydro.motion import LegMotion

    xs = table.x[table.run_slice(r)].astype(np.float64)
    return LegMotion.from_arrays(float(table.runs["dt_s"][r]), xs[:, 1], xs[:, 2], xs[:, 3], xs[:, 4], xs[:, 0])


def with_ef(table: RunTable) -> RunTable:
    """The table with the EF wrench of every tick filled in (the hybrid learns the residual)."""
    if table.ef is not None:
        return table
    from workbench.hydro.ef import EmpiricalFormula

    ef_model = EmpiricalFormula()
    ef = np.empty_like(table.y)
    for r in range(table.n_runs):
        ef[table.run_slice(r)] = ef_model.wrench(motion_of_run(table, r))[0]
    return dataclasses.replace(table, ef=ef)


def window_ends(table: RunTable, runs: np.ndarray, seq_len: int) -> np.ndarray:
    """Last rows of every full window of ``seq_len`` ticks inside the given runs (int64, ascending)."""
    runs = np.asarray(runs, dtype=np.int64)
    n = np.maximum(table.length[runs] - (seq_len - 1), 0)
    if n.sum() == 0:
        return np.zeros(0, dtype=np.int64)
    first = table.start[runs] + seq_len - 1
    # one arange per run, vectorised: run offsets repeated, plus a ramp restarting at each run
    rep_first = np.repeat(first, n)
    ramp = np.arange(n.sum(), dtype=np.int64) - np.repeat(np.cumsum(n) - n, n)
    return rep_first + ramp


@dataclass(frozen=True)
class Normalisation:
    """Per-feature and per-channel mean and standard deviation, fitted on training ticks only."""

    x_mean: tuple[float, ...]
    x_std: tuple[float, ...]
    y_mean: tuple[float, ...]
    y_std: tuple[float, ...]

    def to_dict(self) -> dict:
        """JSON form (saved with the model)."""
        return {"features": list(FEATURES), "channels": list(WRENCH_CHANNELS), **dataclasses.asdict(self)}

    @classmethod
    def from_dict(cls, d: dict) -> "Normalisation":
        """Inverse of :meth:`to_dict`."""
        return cls(*(tuple(float(v) for v in d[k]) for k in ("x_mean", "x_std", "y_mean", "y_std")))

    def arrays(self) -> tuple[np.ndarray, ...]:
        """x_mean, x_std, y_mean, y_std as float32 arrays."""
        return tuple(np.asarray(v, np.float32) for v in (self.x_mean, self.x_std, self.y_mean, self.y_std))


def fit_normalisation(table: RunTable, runs: np.ndarray) -> Normalisation:
    """Mean and std of inputs and wrench over the given runs' ticks (run by run: no big copies).

    A constant input (e.g. a single flow speed) gets std 1 so it passes through centred.
    """
    sx, sxx = np.zeros(table.x.shape[1]), np.zeros(table.x.shape[1])
    sy, syy = np.zeros(table.y.shape[1]), np.zeros(table.y.shape[1])
    n = 0
    for r in runs:
        sl = table.run_slice(int(r))
        xs, ys = table.x[sl].astype(np.float64), table.y[sl].astype(np.float64)
        sx += xs.sum(0)
        sxx += (xs * xs).sum(0)
        sy += ys.sum(0)
        syy += (ys * ys).sum(0)
        n += len(xs)
    if n == 0:
        raise DataError("no training ticks to fit the normalisation on")

    def stats(s, ss):
        mean = s / n
        std = np.sqrt(np.maximum(ss / n - mean * mean, 0.0))
        scale = np.maximum(np.abs(mean), 1.0)
        std = np.where(std > 1e-6 * scale, std, 1.0)
        return tuple(mean.tolist()), tuple(std.tolist())

    xm, xsd = stats(sx, sxx)
    ym, ysd = stats(sy, syy)
    return Normalisation(xm, xsd, ym, ysd)
