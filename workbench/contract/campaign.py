"""campaign.toml (contract section 1) parsed into frozen dataclasses, with every violation collected.

``load_campaign`` raises the first problem as a :class:`ContractError`; ``check_manifest``
returns all of them, so ``workbench campaign validate`` can list every violation at once.
File contents (columns, timestamps, frames) are checked by the readers in ``workbench.ingest``.
"""

from __future__ import annotations

import datetime as _dt
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import numpy as np

from workbench.contract.columns import (
    CAMPAIGN_ID_PATTERN,
    CAMPAIGN_SCHEMA,
    FACILITIES,
    HEADINGS,
    TUNNEL_MOTION_PARAMS,
    TUNNEL_OPTIONAL_DEFAULTS,
)
from workbench.contract.limits import DEFAULT_LIMITS, Limits, manifest_faults
from workbench.contract.unique import first_of_each_id
from workbench.errors import ContractError

_RUN_FILE_KEYS = ("loadcell", "motion", "carriage", "mcap")


@dataclass(frozen=True)
class LoadCellSpec:
    """The ``[loadcell]`` table."""

    model: str
    rate_hz: float
    full_scale: tuple[float, ...] | None = None
    calibration: tuple[tuple[float, ...], ...] | None = None

    def calibration_matrix(self) -> np.ndarray | None:
        """The 6x6 counts-to-SI matrix, or None when the manifest has none."""
        return None if self.calibration is None else np.array(self.calibration, dtype=float)


@dataclass(frozen=True)
class MotionSpec:
    """The ``[motion]`` table (water tunnel only)."""

    rate_hz: float
    feedback: bool = False


@dataclass(frozen=True)
class RunSpec:
    """One ``[[runs]]`` entry. File paths are resolved and checked to lie inside the campaign."""

    id: str
    flow_speed_mps: float
    params: Mapping[str, float] = field(default_factory=dict)
    heading: str | None = None
    cycles: int | None = None
    loadcell: Path | None = None
    motion: Path | None = None
    carriage: Path | None = None
    mcap: Path | None = None

    def files(self) -> list[Path]:
        """The raw files this run reads."""
        return [p for p in (self.loadcell, self.motion, self.carriage, self.mcap) if p is not None]


@dataclass(frozen=True)
class Campaign:
    """A parsed campaign folder."""

    root: Path
    id: str
    facility: str
    date: _dt.date | None
    description: str
    loadcell: LoadCellSpec
    motion: MotionSpec | None
    runs: tuple[RunSpec, ...]
    #: project extension (not contract v1): ``[tunnel] test_section_area_m2``, the test section's
    #: cross-section (m^2), optional; ``diagnose`` gives ``tunnel_blockage`` Maskell's prior from it
    test_section_area_m2: float | None = None

    @property
    def manifest(self) -> Path:
        """Path of campaign.toml."""
        return self.root / "campaign.toml"

    @property
    def is_tunnel(self) -> bool:
        """True for a water-tunnel campaign."""
        return self.facility == "water_tunnel"

    def run(self, run_id: str) -> RunSpec:
        """The run with this id."""
        for r in self.runs:
            if r.id == run_id:
                return r
        raise ContractError("no such run", path=self.manifest, run=run_id)


class _Collector:
    def __init__(self, manifest: Path):
        self.manifest = manifest
        self.errors: list[ContractError] = []

    def add(self, fault: str, *, run: str | None = None, where: str | None = None, hint: str | None = None):
        self.errors.append(ContractError(fault, path=self.manifest, run=run, where=where, hint=hint))


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _resolve_inside(root: Path, rel: Any, col: _Collector, run: str, key: str) -> Path | None:
    if not isinstance(rel, str) or not rel:
        col.add(f"'{key}' must be a relative path string", run=run, where=f"field {key}")
        return None
    p = Path(rel)
    if p.is_absolute():
        col.add(f"'{key}' = {rel!r} is absolute; paths must be relative to the campaign folder",
                run=run, where=f"field {key}")
        return None
    full = (root / p).resolve()
    if not full.is_relative_to(root.resolve()):
        col.add(f"'{key}' = {rel!r} escapes the campaign folder", run=run, where=f"field {key}")
        return None
    return root / p


def _parse_tunnel(t: Any, col: _Collector) -> float | None:
    """The optional ``[tunnel]`` table (a project extension): ``test_section_area_m2`` or nothing."""
    if t is None:
        return None
    area = _number(t.get("test_section_area_m2")) if isinstance(t, dict) else None
    if area is None or area <= 0:
        col.add("test_section_area_m2 must be a positive number (m^2)", where="[tunnel] test_section_area_m2")
        return None
    return area


def _parse_loadcell(t: Any, col: _Collector, needs_calibration: bool) -> LoadCellSpec:
    if not isinstance(t, dict):
        col.add("missing [loadcell] table", where="[loadcell]")
        return LoadCellSpec(model="?", rate_hz=float("nan"))
    rate = _number(t.get("rate_hz"))
    if rate is None or rate <= 0:
        col.add("rate_hz must be a positive number", where="[loadcell] rate_hz")
        rate = float("nan")
    fs = t.get("full_scale")
    full_scale = None
    if fs is not None:
        vals = [_number(v) for v in fs] if isinstance(fs, list) else []
        if len(vals) != 6 or any(v is None or v <= 0 for v in vals):
            col.add("full_scale must be 6 positive numbers", where="[loadcell] full_scale")
        else:
            full_scale = tuple(vals)
    cal = t.get("calibration")
    calibration = None
    if cal is not None:
        ok = isinstance(cal, list) and len(cal) == 6 and all(isinstance(r, list) and len(r) == 6 for r in cal)
        rows = [[_number(v) for v in r] for r in cal] if ok else []
        if not ok or any(v is None for r in rows for v in r):
            col.add("calibration must be a 6x6 matrix of numbers", where="[loadcell] calibration")
        elif abs(np.linalg.det(np.array(rows, float))) < 1e-300:
            col.add("calibration matrix is singular", where="[loadcell] calibration")
        else:
            calibration = tuple(tuple(r) for r in rows)
    if needs_calibration and calibration is None and not any(e.where == "[loadcell] calibration" for e in col.errors):
        col.add("runs use .bin captures but [loadcell] has no calibration matrix", where="[loadcell] calibration")
    return LoadCellSpec(model=str(t.get("model", "")), rate_hz=rate, full_scale=full_scale, calibration=calibration)


def _parse_run(i: int, t: Any, root: Path, facility: str, col: _Collector) -> RunSpec | None:
    where = f"[[runs]] #{i + 1}"
    if not isinstance(t, dict):
        col.add("run entry is not a table", where=where)
        return None
    rid = t.get("id")
    if not isinstance(rid, str) or not re.match(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$", rid):
        col.add(f"run id {rid!r} is missing or not a simple name", where=where)
        return None
    speed = _number(t.get("flow_speed_mps"))
    if speed is None or speed < 0:
        col.add("flow_speed_mps must be a non-negative number", run=rid, where="field flow_speed_mps")
        speed = float("nan")
    files = {key: _resolve_inside(root, t[key], col, rid, key) if key in t else None for key in _RUN_FILE_KEYS}
    params: dict[str, float] = {}
    heading = None
    if facility == "water_tunnel":
        params = _tunnel_run_params(t, rid, col)
        needed = ("loadcell", "motion")
    else:
        heading = _towing_run_heading(t, rid, col)
        needed = ("loadcell", "carriage")
    _check_run_files(t, rid, needed, col)
    return RunSpec(id=rid, flow_speed_mps=speed, params=MappingProxyType(params), heading=heading,
                   cycles=_parse_cycles(t.get("cycles"), rid, col), **files)


def _tunnel_run_params(t: dict, rid: str, col: _Collector) -> dict[str, float]:
    """A water-tunnel run's motion parameters (optional ones defaulted); it has no carriage or heading."""
    params: dict[str, float] = {}
    for key in TUNNEL_MOTION_PARAMS:
        num = _number(t.get(key, TUNNEL_OPTIONAL_DEFAULTS.get(key)))
        if num is None:
            col.add(f"'{key}' is missing or not a number", run=rid, where=f"field {key}")
        else:
            params[key] = num
    if "frequency_hz" in params and params["frequency_hz"] <= 0:
        col.add("frequency_hz must be positive", run=rid, where="field frequency_hz")
    if "carriage" in t or "heading" in t:
        col.add("a water-tunnel run has no 'carriage' or 'heading'", run=rid)
    return params


def _towing_run_heading(t: dict, rid: str, col: _Collector) -> Any:
    """A towing-tank run's heading (checked against HEADINGS); it has no motion file."""
    heading = t.get("heading")
    if heading not in HEADINGS:
        col.add(f"heading must be one of {HEADINGS}, got {heading!r}", run=rid, where="field heading")
    if "motion" in t:
        col.add("a towing-tank run has no 'motion' file", run=rid)
    return heading


def _check_run_files(t: dict, rid: str, needed: tuple[str, str], col: _Collector) -> None:
    """A run gives either an ``mcap`` or the facility's file pair ``needed``, not both."""
    if "mcap" in t:
        extra = [k for k in needed if k in t]
        if extra:
            col.add(f"give either 'mcap' or the file pair {needed}, not both", run=rid)
    else:
        for k in needed:
            if k not in t:
                col.add(f"missing '{k}' file (or 'mcap')", run=rid, where=f"field {k}")


def _parse_cycles(cycles: Any, rid: str, col: _Collector) -> int | None:
    """The optional ``cycles``: a positive integer that fits the processed int32 column, else None."""
    if cycles is not None and (not isinstance(cycles, int) or isinstance(cycles, bool) or cycles <= 0):
        col.add("cycles must be a positive integer", run=rid, where="field cycles")
        return None
    if cycles is not None and cycles > 2**31 - 1:  # the processed column is int32
        col.add(f"cycles = {cycles} is too large (at most {2**31 - 1}); a typo?", run=rid, where="field cycles",
                hint="give the number of motion cycles the run recorded")
        return None
    return cycles


def check_manifest(root: str | Path, limits: Limits | None = DEFAULT_LIMITS
                   ) -> tuple[Campaign | None, list[ContractError]]:
    """Parse ``root/campaign.toml``; return the campaign (None if unusable) and every violation found.

    Values outside the rig's ranges (:mod:`workbench.contract.limits`; ``limits=None`` skips them)
    count as violations too. A UTF-8 byte-order mark (spreadsheet and Windows editors) is accepted.
    """
    root = Path(root)
    manifest = root / "campaign.toml"
    doc = _read_manifest(root, manifest)
    if isinstance(doc, ContractError):
        return None, [doc]
    col = _Collector(manifest)
    schema = doc.get("schema")
    if schema != CAMPAIGN_SCHEMA:
        col.add(f"unknown schema version {schema!r}", where="field schema",
                hint=f"this workbench reads {CAMPAIGN_SCHEMA!r}")
        return None, col.errors
    cid = _parse_id(doc.get("id"), root, col)
    facility = doc.get("facility")
    if facility not in FACILITIES:
        col.add(f"facility must be one of {FACILITIES}, got {facility!r}", where="field facility")
        return None, col.errors
    date = _parse_date(doc.get("date"), col)
    raw_runs = doc.get("runs")
    if not isinstance(raw_runs, list) or not raw_runs:
        col.add("no [[runs]] entries", where="[[runs]]")
        raw_runs = []
    needs_cal = any(isinstance(r, dict) and str(r.get("loadcell", "")).endswith(".bin") for r in raw_runs)
    loadcell = _parse_loadcell(doc.get("loadcell"), col, needs_cal)
    motion = _parse_motion(doc.get("motion"), col) if facility == "water_tunnel" else None
    runs = _parse_runs(raw_runs, root, facility, col)
    camp = Campaign(root=root, id=cid, facility=facility, date=date,
                    description=str(doc.get("description", "")), loadcell=loadcell,
                    motion=motion, runs=tuple(runs), test_section_area_m2=_parse_tunnel(doc.get("tunnel"), col))
    if limits is not None:
        col.errors.extend(manifest_faults(camp, limits))
    return camp, col.errors


def _read_manifest(root: Path, manifest: Path) -> dict | ContractError:
    """The parsed TOML of ``manifest`` (a UTF-8 BOM accepted), or the one error that makes it unreadable."""
    if not root.is_dir():
        return ContractError("campaign folder does not exist", path=root)
    if not manifest.is_file():
        return ContractError("missing campaign.toml", path=root)
    try:
        return tomllib.loads(manifest.read_text(encoding="utf-8-sig"))
    except UnicodeDecodeError as exc:
        return ContractError(f"not UTF-8 text (byte {exc.start})", path=manifest, hint="save campaign.toml as UTF-8")
    except tomllib.TOMLDecodeError as exc:
        return ContractError(f"not valid TOML: {exc}", path=manifest,
                             hint="see the campaign.toml example in docs/campaigns.md")


def _parse_id(cid: Any, root: Path, col: _Collector) -> str:
    """The campaign id: it matches CAMPAIGN_ID_PATTERN and the folder's name."""
    if not isinstance(cid, str) or not re.match(CAMPAIGN_ID_PATTERN, cid):
        col.add(f"campaign id {cid!r} must match {CAMPAIGN_ID_PATTERN}", where="field id")
        return str(cid)
    if cid != root.name:
        col.add(f"campaign id {cid!r} differs from the folder name {root.name!r}", where="field id")
    return cid


def _parse_date(date: Any, col: _Collector) -> _dt.date | None:
    """The optional TOML date."""
    if date is not None and not isinstance(date, _dt.date):
        col.add("date must be a TOML date (YYYY-MM-DD)", where="field date")
        return None
    return date


def _parse_motion(mt: Any, col: _Collector) -> MotionSpec:
    """The ``[motion]`` table of a water-tunnel campaign (a missing or bad rate is NaN, feedback off)."""
    rate = _number(mt.get("rate_hz")) if isinstance(mt, dict) else None
    if rate is None or rate <= 0:
        col.add("[motion] rate_hz must be a positive number", where="[motion] rate_hz")
        rate = float("nan")
    fb = mt.get("feedback", False) if isinstance(mt, dict) else False
    if not isinstance(fb, bool):
        col.add("[motion] feedback must be true or false", where="[motion] feedback")
        fb = False
    return MotionSpec(rate_hz=rate, feedback=fb)


def _parse_runs(raw_runs: list, root: Path, facility: str, col: _Collector) -> list[RunSpec]:
    """The usable runs, in the file's order; a repeated id is an error and only its first run is kept."""
    return first_of_each_id(((i, _parse_run(i, t, root, facility, col)) for i, t in enumerate(raw_runs)),
                            lambda i, r: col.add("duplicate run id", run=r.id))


def run_errors(errors: list[ContractError]) -> dict[str | None, list[ContractError]]:
    """Group errors by run id (None: campaign-level)."""
    out: dict[str | None, list[ContractError]] = {}
    for e in errors:
        out.setdefault(e.run, []).append(e)
    return out


def load_campaign(root: str | Path, limits: Limits | None = DEFAULT_LIMITS) -> Campaign:
    """Parse a campaign folder's manifest or raise its first campaign-level violation.

    Run-level violations do not raise here: they are returned by :func:`check_manifest`
    and handled per run by ingest (refuse the campaign, or skip bad runs).
    """
    camp, errors = check_manifest(root, limits)
    campaign_level = [e for e in errors if e.run is None]
    if camp is None or campaign_level:
        raise (campaign_level or errors)[0]
    return camp
