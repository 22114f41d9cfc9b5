"""The diagnosis's view of a processed tunnel campaign: runs padded into batches, the held-out split, blocks.

Runs are split into training and held-out runs *by their motion parameters* (every flow speed
of a parameter set goes to the same side), from a hash of the rounded parameters, so a
re-measured campaign splits the same way. Within each run the analysis ticks (edges trimmed,
optionally strided) are cut into blocks of a few seconds: the units of the significance tests
and of the autocorrelation-robust parameter covariance.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from workbench.contract.columns import TUNNEL_MOTION_PARAMS, WRENCH_CHANNELS
from workbench.errors import DataError, SettingError
from workbench.hydro.motion import LegMotion, RunMotion, runs_from_frame


@dataclass(frozen=True)
class DataSettings:
    """How runs become analysis ticks (``pipelines/diagnose.yaml`` section ``data``)."""

    heldout_fraction: float = 0.3
    #: decimals the motion parameters are rounded to before hashing (the split key)
    split_decimals: int = 3
    #: a motion parameter the held-out runs must cover: every value of it that two or more parameter sets
    #: share gets a held-out set (a flow tone at a harmonic of every held-out gait cannot be tested); "": none
    split_cover: str = ""
    #: seconds cut from both ends of the moving part of every run (filter and lag transients)
    edge_trim_s: float = 0.5
    #: also fit on the pre-run rest stretch (time_s < 0) when the processed file keeps it
    include_rest: bool = False
    #: use every n-th analysis tick in fits (the data are low-passed far below the tick rate)
    tick_stride: int = 2
    #: at most this many runs (deterministic subsample, all speeds of a set together); 0 = all. The
    #: shipped pipelines/diagnose.yaml's value, so the command gives the same diagnosis from any folder
    #: (run outside the project with the default 0, the demo campaign's 192 runs claimed a fy-from-tx
    #: crosstalk and a lift the clean truth lacks; docs/diagnose.md, "What is weak")
    max_runs: int = 96
    #: runs per padded batch (memory)
    chunk_runs: int = 48
    #: block length for significance tests and robust covariances (s)
    block_s: float = 2.0

    def __post_init__(self):
        if self.split_cover and self.split_cover not in TUNNEL_MOTION_PARAMS:
            raise SettingError(f"split_cover {self.split_cover!r} is not a motion parameter; "
                             f"one of {', '.join(TUNNEL_MOTION_PARAMS)}, or \"\" for none")


@dataclass
class RunSet:
    """A batch of runs padded to one length ``T`` (edge values repeated); arrays are ``(B, T, ...)``."""

    run_ids: tuple[str, ...]
    index: np.ndarray          # (B,) position of each run in the campaign's run list
    dt_s: float
    time_s: np.ndarray         # (B, T)
    motion: LegMotion
    y: np.ndarray              # (B, T, 6) measured wrench
    valid: np.ndarray          # (B, T) real (not padding)
    fit: np.ndarray            # (B, T) analysis ticks (moving part, trimmed)
    rest: np.ndarray           # (B, T) pre-run rest ticks (time_s < 0)
    flow: np.ndarray           # (B,)
    freq: np.ndarray           # (B,) gait frequency (Hz), NaN if unknown
    params: list[dict]
    heldout: bool
    #: (B, T, 6) known addition to the model's (low-passed) prediction, e.g. a reference misfit; None: none
    offset: np.ndarray | None = None
    #: (B, T, 6) its flow sensitivity U d(offset)/dU; None: none
    flow_offset: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        """(B, T)."""
        return self.time_s.shape


@dataclass
class Campaign:
    """All runs of a campaign as training and held-out batches."""

    campaign_id: str
    runs: list[RunMotion]
    heldout: np.ndarray                   # (n_runs,) bool
    train_sets: list[RunSet]
    heldout_sets: list[RunSet]
    dt_s: float
    settings: DataSettings
    skipped: list[str] = field(default_factory=list)
    #: run index -> (T, 6) known addition to the model's prediction (``--reference``)
    offsets: dict[int, np.ndarray] | None = None
    flow_offsets: dict[int, np.ndarray] | None = None

    @property
    def sets(self) -> list[RunSet]:
        """Training then held-out batches."""
        return self.train_sets + self.heldout_sets

    def run_ids(self, heldout: bool | None = None) -> list[str]:
        """Run ids (optionally only training or held-out)."""
        return [r.run_id for r, h in zip(self.runs, self.heldout, strict=False) if heldout is None or h == heldout]


def parameter_key(params: dict, decimals: int) -> str:
    """The split key of a run: its rounded motion parameters (flow speed excluded)."""
    # "+ 0.0" turns a negative zero into zero: -0.0 and 0.0 are the same parameter
    return ";".join(f"{round(float(params.get(p, 0.0)), decimals) + 0.0:.{decimals}f}".join((f"{p}=", ""))
                    for p in TUNNEL_MOTION_PARAMS if p in params)


def _unit_hash(key: str) -> float:
    return int.from_bytes(hashlib.sha256(key.encode()).digest()[:8], "big") / 2.0**64


def heldout_mask(runs: list[RunMotion], fraction: float, decimals: int = 3, cover: str = "") -> np.ndarray:
    """Held-out runs: parameter sets whose key hashes below ``fraction`` (at least one set, never all).

    ``cover``: a motion parameter (the gait frequency) whose every value shared by two or more sets
    gets a held-out set (the lowest hash among them) and keeps a training set. The choice depends on
    the sets alone, so a re-measured campaign of the same sets splits the same way.
    """
    keys = [parameter_key(dict(r.params), decimals) if r.params else r.run_id for r in runs]
    uniq = sorted(set(keys))
    h = {k: _unit_hash(k) for k in uniq}
    held = {k for k in uniq if h[k] < fraction}
    if cover and fraction > 0:
        groups: dict[float, set[str]] = {}
        for k, r in zip(keys, runs, strict=True):
            if r.params and cover in r.params:
                groups.setdefault(round(float(r.params[cover]), decimals), set()).add(k)
        for members in (m for m in groups.values() if len(m) >= 2):
            if not held & members:
                held.add(min(members, key=h.get))
            if members <= held:
                held.discard(max(members, key=h.get))
    if len(uniq) >= 2 and fraction > 0:
        if not held:
            held = {min(uniq, key=h.get)}
        if len(held) == len(uniq):
            held.discard(max(uniq, key=h.get))
    return np.array([k in held for k in keys])


def crossfit_folds(runs: list[RunMotion], heldout: np.ndarray, folds: int, decimals: int = 3) -> np.ndarray:
    """Per run, its fold of a cross-fitted test: 0 for the held-out sets, 1 .. ``folds`` - 1 for the training sets.

    The training sets go to the folds in turn, in the order of their key's hash, so the folds
    (like the split) depend on the sets alone and a re-measured campaign folds the same way; all
    flow speeds of a set share its fold. Fold 0 is the split's held-out part, so a cross-fitted
    test sees the split's held-out blocks exactly as the split does, and the rest besides.
    """
    keys = [parameter_key(dict(r.params), decimals) if r.params else r.run_id for r in runs]
    held = np.asarray(heldout, bool)
    train = sorted({k for k, h in zip(keys, held, strict=True) if not h}, key=_unit_hash)
    fold_of = {k: 1 + i % max(folds - 1, 1) for i, k in enumerate(train)}
    return np.array([0 if h else fold_of[k] for k, h in zip(keys, held, strict=True)], int)


def _subsample(runs: list[RunMotion], max_runs: int, decimals: int) -> list[RunMotion]:
    """A deterministic subsample of whole parameter sets (by hash order) of at most ``max_runs`` runs."""
    if not max_runs or len(runs) <= max_runs:
        return runs
    by_key: dict[str, list[RunMotion]] = {}
    for r in runs:
        by_key.setdefault(parameter_key(dict(r.params), decimals), []).append(r)
    keep: list[RunMotion] = []
    for key in sorted(by_key, key=lambda k: _unit_hash("sub:" + k)):
        if len(keep) + len(by_key[key]) > max_runs and keep:
            continue
        keep.extend(by_key[key])
    order = {id(r): i for i, r in enumerate(runs)}
    return sorted(keep, key=lambda r: order[id(r)])


def _pad(x: np.ndarray, n: int) -> np.ndarray:
    if len(x) >= n:
        return x[:n]
    return np.concatenate([x, np.repeat(x[-1:], n - len(x), axis=0)], axis=0)


def derivative4(x: np.ndarray, dt: float) -> np.ndarray:
    """Time derivative along the last axis, fourth-order central differences (second order at the ends).

    The joint accelerations the models see: a plain central difference errs by (w dt)^2 / 6, which
    at the third gait harmonic and 65 Hz is half a percent of the inertial force, enough to show
    in the best-resolved channel.
    """
    out = np.gradient(x, dt, axis=-1, edge_order=2) if x.shape[-1] > 2 else np.zeros_like(x)
    if x.shape[-1] >= 5:
        out[..., 2:-2] = (x[..., :-4] - 8 * x[..., 1:-3] + 8 * x[..., 3:-1] - x[..., 4:]) / (12 * dt)
    return out


def make_runset(runs: list[RunMotion], index: list[int], dt: float, settings: DataSettings, heldout: bool,
                offsets: dict[int, np.ndarray] | None = None,
                flow_offsets: dict[int, np.ndarray] | None = None) -> RunSet:
    """Pad ``runs`` to a common length and mark their analysis and rest ticks (``offsets`` by run index)."""
    n = max(len(r.time_s) for r in runs)
    b = len(runs)
    time = np.empty((b, n))
    arrays = {k: np.empty((b, n)) for k in ("th", "tk", "wh", "wk", "u")}
    y = np.empty((b, n, 6))
    valid = np.zeros((b, n), bool)
    fit = np.zeros((b, n), bool)
    rest = np.zeros((b, n), bool)
    for i, r in enumerate(runs):
        m = r.motion
        t = r.time_s
        k = len(t)
        time[i] = np.concatenate([t, t[-1] + dt * np.arange(1, n - k + 1)])
        for key, arr in (("th", m.theta_h_deg), ("tk", m.theta_k_deg), ("wh", m.omega_h_dps),
                         ("wk", m.omega_k_dps), ("u", m.flow_speed_mps)):
            arrays[key][i] = _pad(arr[0], n)
        y[i] = _pad(r.wrench, n)
        valid[i, :k] = True
        moving = t >= 0
        t_end = t[-1]
        ok = moving & (t >= settings.edge_trim_s) & (t <= t_end - settings.edge_trim_s)
        if settings.include_rest:
            ok |= (t < 0) & (t >= t[0] + settings.edge_trim_s)
        fit[i, :k] = ok
        rest[i, :k] = t < 0
    motion = LegMotion.from_arrays(dt, arrays["th"], arrays["tk"], arrays["wh"], arrays["wk"], arrays["u"],
                                   derivative4(arrays["wh"], dt), derivative4(arrays["wk"], dt))
    freq = np.array([float(r.params.get("frequency_hz", np.nan)) for r in runs])
    def table(src):
        if not src:
            return None
        out = np.zeros((b, n, 6))
        for i, j in enumerate(index):
            if int(j) in src:
                out[i] = _pad(src[int(j)], n)
        return out

    off, flow_off = table(offsets), table(flow_offsets)
    return RunSet(run_ids=tuple(r.run_id for r in runs), index=np.asarray(index), dt_s=dt, time_s=time,
                  motion=motion, y=y, valid=valid, fit=fit, rest=rest,
                  flow=np.array([r.flow_speed_mps for r in runs]), freq=freq,
                  params=[dict(r.params) for r in runs], heldout=heldout, offset=off,
                  flow_offset=flow_off)


def _chunks(idx: list[int], runs: list[RunMotion], size: int) -> list[list[int]]:
    """Group run indices by length (little padding), at most ``size`` per group."""
    idx = sorted(idx, key=lambda i: len(runs[i].time_s))
    return [idx[i:i + size] for i in range(0, len(idx), max(1, size))]


def prepare(frame, settings: DataSettings | None = None, source: str = "processed frame") -> Campaign:
    """Split a processed tunnel frame (contract section 3, measured rows) into padded batches."""
    settings = settings or DataSettings()
    missing = [c for c in ("run_id", "time_s", "flow_speed_mps", "theta_h_deg", "theta_k_deg", "omega_h_dps",
                           "omega_k_dps", *WRENCH_CHANNELS) if c not in frame.columns]
    if missing:
        raise DataError(f"missing column(s) {missing} (a water-tunnel processed dataset is needed)", path=source)
    if "interpolated" in frame.columns:
        import polars as pl

        frame = frame.filter(~pl.col("interpolated"))
    runs = [r for r in runs_from_frame(frame) if len(r.time_s) > 8]
    skipped = []
    good = []
    for r in runs:
        arrays = [r.motion.theta_h_deg, r.motion.theta_k_deg, r.motion.omega_h_dps, r.motion.omega_k_dps, r.wrench]
        if not all(np.isfinite(a).all() for a in arrays):
            skipped.append(r.run_id)
            continue
        good.append(r)
    runs = _subsample(good, settings.max_runs, settings.split_decimals)
    if len(runs) < 2:
        raise DataError(f"{len(runs)} usable run(s); the diagnosis needs at least two", path=source)
    dts = np.array([r.motion.dt_s for r in runs])
    dt = float(np.median(dts))
    if np.any(np.abs(dts - dt) > 0.02 * dt):
        bad = runs[int(np.argmax(np.abs(dts - dt)))].run_id
        raise DataError(f"tick interval differs between runs ({dts.min():.4g}-{dts.max():.4g} s)", path=source,
                        run=bad, hint="resample the runs onto one control tick")
    held = heldout_mask(runs, settings.heldout_fraction, settings.split_decimals, settings.split_cover)
    train_idx = [i for i in range(len(runs)) if not held[i]]
    held_idx = [i for i in range(len(runs)) if held[i]]
    if not train_idx or not held_idx:
        n_sets = len({tuple(sorted(r.params.items())) for r in runs})
        raise DataError(f"{len(runs)} run(s) of {n_sets} motion-parameter set(s) leave "
                        f"{'no training' if not train_idx else 'no held-out'} runs (whole sets are held out, "
                        f"fraction {settings.heldout_fraction:g})", path=source,
                        hint="diagnose a campaign with more parameter sets, or raise data.max_runs")
    train_sets = [make_runset([runs[i] for i in c], c, dt, settings, False)
                  for c in _chunks(train_idx, runs, settings.chunk_runs)]
    held_sets = [make_runset([runs[i] for i in c], c, dt, settings, True)
                 for c in _chunks(held_idx, runs, settings.chunk_runs)]
    cid = runs[0].campaign_id or "campaign"
    return Campaign(campaign_id=cid, runs=runs, heldout=held, train_sets=train_sets, heldout_sets=held_sets,
                    dt_s=dt, settings=settings, skipped=skipped)


@dataclass(frozen=True)
class Blocks:
    """Analysis ticks of a RunSet, strided and cut into blocks: gather indices into the flat (B*T) axis."""

    ticks: np.ndarray      # (nb, L) flat tick indices, -1 = padding
    run: np.ndarray        # (nb,) campaign run index
    order: np.ndarray      # (nb,) block number within its run


def make_blocks(rs: RunSet, stride: int, block_s: float) -> Blocks:
    """Cut the (strided) analysis ticks of each run into consecutive blocks of about ``block_s``."""
    b, t = rs.shape
    length = max(4, int(round(block_s / (rs.dt_s * stride))))
    rows, runs, order = [], [], []
    for i in range(b):
        idx = np.flatnonzero(rs.fit[i])[::stride]
        if len(idx) == 0:
            continue
        nblk = max(1, int(round(len(idx) / length)))
        for j, part in enumerate(np.array_split(idx, nblk)):
            row = np.full(int(np.ceil(len(idx) / nblk)) + 1, -1)
            row[:len(part)] = part + i * t
            rows.append(row)
            runs.append(rs.index[i])
            order.append(j)
    width = max(len(r) for r in rows) if rows else 1
    ticks = np.full((len(rows), width), -1)
    for k, r in enumerate(rows):
        ticks[k, :len(r)] = r
    return Blocks(ticks=ticks, run=np.asarray(runs, int), order=np.asarray(order, int))
