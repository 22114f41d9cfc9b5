"""Reader for the contract's CSV logs (load cell, leg motion, carriage), parsed by polars."""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import polars as pl

from workbench.errors import ContractError, DataError
from workbench.ingest.readers.base import ReadSpec, header_fault, read_raw
from workbench.ingest.streams import Stream, csv_line

_NON_SPACE = re.compile(rb"\S")


class CsvReader:
    """One CSV log: exact header check, numeric parse, truncation and ragged-line detection."""

    def __init__(self, path: Path, role: str, spec: ReadSpec):
        self.path = Path(path)
        self.role = role
        self.spec = spec

    def _fail(self, cls, fault, where=None, hint=None):
        raise cls(fault, path=self.path, run=self.spec.run, where=where, hint=hint)

    def read(self) -> dict[str, Stream]:
        """Parse the file into one stream."""
        data, sha = read_raw(self.path, self.spec.run)
        expected = self.spec.columns(self.role)
        if data.startswith(b"\xef\xbb\xbf"):  # UTF-8 byte-order mark from spreadsheet exports
            data = data[3:]
        nl = data.find(b"\n")
        header_line = data if nl < 0 else data[:nl]
        try:
            found = [c.strip() for c in header_line.decode("utf-8").strip().split(",")]
        except UnicodeDecodeError:
            self._fail(ContractError, "header is not UTF-8 text", "line 1")
        fault = header_fault(found, expected)
        if fault:
            hint = None
            if self.role == "motion" and any(c.endswith("_meas_deg") for c in found) != self.spec.feedback:
                hint = "[motion] feedback in campaign.toml says whether motion logs carry measured angles"
            self._fail(ContractError, fault, "header (line 1)", hint)
        if nl < 0 or _NON_SPACE.search(data, nl + 1) is None:  # (no copy of the body)
            self._fail(DataError, "no data rows after the header")
        if not data.endswith(b"\n"):
            last = data[data.rfind(b"\n") + 1:]
            nfields = last.count(b",") + 1
            if nfields < len(expected):
                line = data.count(b"\n") + 1
                self._fail(DataError, f"truncated file: the last line has {nfields} of {len(expected)} fields",
                           f"line {line}", "the copy or the logger stopped mid-line")
        schema = {c: pl.Float64 for c in expected}
        try:
            df = pl.read_csv(io.BytesIO(data), schema=schema, has_header=True)
        except (pl.exceptions.ComputeError, pl.exceptions.NoDataError, pl.exceptions.ShapeError) as exc:
            self._diagnose(data, expected)
            self._fail(ContractError, f"cannot parse: {str(exc).splitlines()[0]}")
        arrays = {c: df.get_column(c).to_numpy() for c in expected}
        if not all(np.isfinite(a).all() for a in arrays.values()):
            self._diagnose(data, expected)  # ragged lines raise; empty and NaN cells are checked later
        values = {c: arrays[c] for c in expected if c not in ("time_s", "sync")}
        sync = arrays["sync"]
        return {self.role: Stream(role=self.role, path=self.path, time_s=arrays["time_s"],
                                  sync=np.where(np.isfinite(sync), sync, -1.0), values=values, locate=csv_line,
                                  source="csv", sha256=sha)}

    def _diagnose(self, data: bytes, expected: tuple[str, ...]) -> None:
        """Find the first ragged line or non-numeric cell (the slow path, only on bad files)."""
        text = data.decode("utf-8", errors="replace").splitlines()
        for i, line in enumerate(text[1:], start=2):
            if not line.strip():
                continue
            cells = line.split(",")
            if len(cells) != len(expected):
                self._fail(ContractError, f"{len(cells)} fields, expected {len(expected)}", f"line {i}")
            for name, cell in zip(expected, cells, strict=True):
                cell = cell.strip()
                if not cell:
                    continue
                try:
                    float(cell)
                except ValueError:
                    shown = cell if len(cell) <= 20 else cell[:17] + "..."
                    self._fail(ContractError, f"non-numeric value {shown!r} in column {name}", f"line {i}")
