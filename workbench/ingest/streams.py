"""What every reader returns: one device's samples on its own clock, checked against the contract.

A :class:`Stream` is a device log (load cell, leg controller or carriage) after parsing: time
stamps on the device's clock, the trigger level, named value columns. :func:`check_stream`
applies the rules every source shares (no empty logs, strictly increasing time, no gaps,
0/1 trigger levels, short NaN runs bridged and longer ones refused), naming the offending
line, frame or message through the stream's ``locate``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np

from workbench.errors import ContractError, DataError
from workbench.ingest.params import IngestSettings


@dataclass(frozen=True)
class Stream:
    """One device's log: ``time_s`` on its own clock, ``sync`` (0/1), and value columns."""

    role: str
    path: Path
    time_s: np.ndarray
    sync: np.ndarray
    values: dict[str, np.ndarray]
    #: maps a sample index to where it is in the file ("line 17", "frame 3 (byte 96)", ...)
    locate: Callable[[int], str] = field(default=lambda i: f"sample {i}", compare=False, repr=False)
    source: str = "csv"
    sha256: str = ""
    dropped_bytes: int = 0
    dropped_frames: int = 0
    nan_filled: int = 0

    def __len__(self) -> int:
        return len(self.time_s)

    def column_matrix(self, names) -> np.ndarray:
        """Stack the named value columns into an (N, C) array."""
        return np.column_stack([self.values[n] for n in names])


def csv_line(i: int) -> str:
    """Where data row ``i`` sits in a CSV file with one header line."""
    return f"line {i + 2}"


def check_stream(s: Stream, params: IngestSettings, run: str | None,
                 full_scale: tuple[float, ...] | None = None) -> Stream:
    """Apply the shared rules; return the stream with short NaN runs bridged.

    Infinite cells and cells beyond the rig's ranges (``params.limits``: a load-cell cell beyond
    ``full_scale_factor`` x ``full_scale``, an angle beyond ``angle_deg_max``, ...) are refused: they are
    not readings, and bridging them (as NaN gaps are) would hide a broken file.
    Raises :class:`DataError` or :class:`ContractError` naming the file, the run and where.
    """
    def fail(cls, fault, i=None, hint=None):
        raise cls(fault, path=s.path, run=run, where=None if i is None else s.locate(int(i)), hint=hint)

    _check_samples(s, fail)
    _check_timing(s.time_s, params, fail)
    for name, x in s.values.items():
        _check_cells(name, np.asarray(x, float), params.limits, full_scale, fail)
    values, filled = _bridged_values(s.values, params.max_nan_run, fail)
    return replace(s, values=values, nan_filled=s.nan_filled + filled, sync=s.sync.astype(np.int8))


def _check_samples(s: Stream, fail) -> None:
    """Refuse a log with fewer than three samples, a missing or non-finite time stamp, or a trigger level not 0/1."""
    n = len(s.time_s)
    if n == 0:
        fail(DataError, f"no {s.role} samples")
    if n < 3:
        fail(DataError, f"only {n} {s.role} sample(s)")
    bad = ~np.isfinite(s.time_s)
    if bad.any():
        fail(DataError, "missing or non-finite time_s", np.argmax(bad))
    badsync = ~((s.sync == 0) | (s.sync == 1))
    if badsync.any():
        i = int(np.argmax(badsync))
        fail(ContractError, f"sync must be 0 or 1, got {s.sync[i]!r}", i)


def _check_timing(time_s: np.ndarray, params: IngestSettings, fail) -> None:
    """Refuse time stamps that repeat, go back, or leave a gap beyond the larger of the two gap limits."""
    d = np.diff(time_s)
    if (d <= 0).any():
        i = int(np.argmax(d <= 0))
        if d[i] == 0:
            fail(DataError, f"duplicated timestamp time_s = {time_s[i]:.6f} (same as the previous sample)", i + 1)
        fail(DataError, f"non-monotonic timestamps: time_s goes back from {time_s[i]:.6f} to {time_s[i + 1]:.6f}",
             i + 1)
    med = float(np.median(d))
    limit = max(params.max_gap_s, params.gap_factor * med)
    if (d > limit).any():
        i = int(np.argmax(d > limit))
        fail(DataError, f"gap of {d[i]:.3f} s in time_s after {time_s[i]:.6f} (limit {limit:.3f} s)", i + 1)


def _bridged_values(values: dict[str, np.ndarray], max_nan_run: int, fail) -> tuple[dict[str, np.ndarray], int]:
    """Every column with its short NaN runs bridged, and how many cells were filled; a longer run is refused."""
    out, filled = {}, 0
    for name, x in values.items():
        x, k = _bridge_nans(x, max_nan_run, lambda a, b, name=name: fail(
            DataError, f"NaN stretch of {b - a} samples in {name} (up to {max_nan_run} are bridged)", a))
        out[name] = x
        filled += k
    return out, filled


def _check_cells(name: str, x: np.ndarray, limits, full_scale, fail) -> None:
    inf = np.isinf(x)
    if inf.any():
        i = int(np.argmax(inf))
        fail(DataError, f"infinite value {float(x[i])} in column {name}", i,
             "not a reading: fix or re-export the file (an empty cell is read as missing and bridged)")
    top = limits.cell_limit(name, full_scale)
    if top is None:
        return
    with np.errstate(invalid="ignore"):
        beyond = np.abs(x) > top
    if beyond.any():
        i = int(np.argmax(beyond))
        which = (f"{limits.full_scale_factor:g} x the load cell's full scale" if full_scale is not None
                 and name in _WRENCH else "the rig's range")
        key = ("full_scale_factor" if full_scale is not None and name in _WRENCH else
               "force_abs_max_n" if name.endswith("_n") else "torque_abs_max_nm" if name.endswith("_nm")
               else "angle_deg_max" if name.endswith("_deg") else "carriage_position_abs_m_max")
        fail(DataError, f"{name} = {x[i]:g} is beyond {which} ({top:g}; {int(beyond.sum())} such cell(s))", i,
             f"a corrupt cell or a wrong unit: fix the file, or raise ingest.limits.{key} in pipelines/ingest.yaml "
             f"if the rig really reads that")


_WRENCH = ("fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm")


def _bridge_nans(x: np.ndarray, max_run: int, fail) -> tuple[np.ndarray, int]:
    x = np.asarray(x, float)
    bad = ~np.isfinite(x)
    if not bad.any():
        return x, 0
    edges = np.diff(np.concatenate([[0], bad.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    lengths = stops - starts
    worst = int(np.argmax(lengths))
    if lengths[worst] > max_run or starts[0] == 0 and bad.all():
        fail(int(starts[worst]), int(stops[worst]))
    idx = np.arange(len(x))
    good = ~bad
    x = x.copy()
    x[bad] = np.interp(idx[bad], idx[good], x[good])
    return x, int(bad.sum())
