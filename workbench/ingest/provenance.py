"""Processed files on disk: atomic Parquet with an explicit schema and provenance in its metadata.

The file metadata (key ``workbench``, JSON) records the content hash of every raw file, the
workbench version, the ingest parameters, the angle source, the runs left out and the quality
report, so a processed file says where it came from and ingest can tell when it is up to date.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

from workbench import __version__
from workbench.atomic import atomic_path, write_json
from workbench.contract.campaign import Campaign
from workbench.contract.columns import CAMPAIGN_SCHEMA
from workbench.errors import ContractError
from workbench.ingest.schema import FORMAT, METADATA_KEY, columns_for, schema_for

_CHUNK = 1 << 22


def sha256_file(path: str | Path) -> str:
    """Content hash of a file (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            h.update(chunk)
    return h.hexdigest()


def campaign_hashes(campaign: Campaign, known: dict[str, str] | None = None) -> dict[str, str]:
    """sha256 of campaign.toml and of every existing file its runs name (relative paths as keys).

    ``known`` holds hashes already computed while reading (they are not recomputed).
    """
    known = dict(known or {})
    out = {"campaign.toml": known.get("campaign.toml") or sha256_file(campaign.manifest)}
    for run in campaign.runs:
        for p in run.files():
            rel = p.relative_to(campaign.root).as_posix() if p.is_relative_to(campaign.root) else p.as_posix()
            if rel in out:
                continue
            if rel in known:
                out[rel] = known[rel]
            elif p.is_file():
                out[rel] = sha256_file(p)
    return dict(sorted(out.items()))


def quality_path(path: str | Path) -> Path:
    """Where the quality report of a processed file goes: ``<name>.quality.json`` beside it."""
    path = Path(path)
    return path.with_name(path.stem + ".quality.json")


def provenance_of(result) -> dict[str, Any]:
    """The metadata record of an :class:`~workbench.ingest.campaign.IngestResult`."""
    camp = result.campaign
    return {
        "format": FORMAT,
        "contract": CAMPAIGN_SCHEMA,
        "workbench_version": __version__,
        "campaign_id": camp.id,
        "facility": camp.facility,
        "angle_source": result.quality.get("angle_source"),
        "raw_files": result.hashes,
        "params": result.params.recorded(),
        "skip_bad_runs": bool(result.skip_bad_runs),
        "skipped_runs": [{"run_id": e.run, "error": e.format()} for e in result.skipped],
        "interpolation": None,
        "quality": result.quality,
    }


def to_arrow(frame: pl.DataFrame, facility: str, metadata: dict[str, Any]) -> pa.Table:
    """The frame as an Arrow table with the processed schema (columns beyond it kept as they are)."""
    schema = schema_for(facility)
    missing = [c for c in columns_for(facility) if c not in frame.columns]
    if missing:
        raise ContractError(f"processed frame lacks column(s) {missing}")
    extra = [c for c in frame.columns if c not in schema.names]
    table = frame.select([*schema.names, *extra]).to_arrow()
    fields = list(schema) + [pa.field(c, table.schema.field(c).type) for c in extra]
    full = pa.schema(fields)
    table = table.cast(full)
    return table.replace_schema_metadata({METADATA_KEY: json.dumps(metadata, sort_keys=True,
                                                                   default=_json_default).encode()})


def _json_default(o):
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_table(table: pa.Table, path: str | Path) -> None:
    """Write an Arrow table to Parquet atomically (the old file stays until the new one is whole)."""
    with atomic_path(path, suffix=".parquet.tmp") as tmp:
        # dictionary encoding only where it pays (the id columns); constant floats compress anyway
        strings = [f.name for f in table.schema if pa.types.is_string(f.type) or pa.types.is_large_string(f.type)]
        pq.write_table(table, tmp, compression="zstd", use_dictionary=strings)


def write_processed(result, path: str | Path, *, quality: bool = True) -> Path:
    """Write an ingest result atomically: the Parquet file and ``<name>.quality.json`` beside it.

    The two form one set with the Parquet file as its authority: its metadata holds the quality
    report, and :func:`sync_quality` rewrites a missing or stale ``quality.json`` from it (a kill
    between the two renames leaves the new Parquet beside the old report until the next ingest).
    """
    from workbench.atomic import check_not_raw

    path = Path(path)
    check_not_raw(path)
    check_not_raw(quality_path(path))
    meta = provenance_of(result)
    write_table(to_arrow(result.frame, result.campaign.facility, meta), path)
    if quality:
        write_json(quality_path(path), result.quality)
    return path


def sync_quality(path: str | Path) -> bool:
    """Make ``<name>.quality.json`` match the quality report in the Parquet file's metadata.

    Returns True when it was missing or stale and has been rewritten.
    """
    path = Path(path)
    want = read_provenance(path).get("quality")
    q = quality_path(path)
    try:
        have = json.loads(q.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        have = None
    if have == want:
        return False
    write_json(q, want)
    return True


def read_provenance(path: str | Path) -> dict[str, Any]:
    """The provenance record of a processed file (raises ContractError if it has none)."""
    path = Path(path)
    if not path.is_file():
        raise ContractError("processed file not found", path=path)
    try:
        meta = pq.read_schema(path).metadata or {}
    except (pa.ArrowInvalid, OSError) as exc:
        raise ContractError(f"not a readable Parquet file: {exc}".splitlines()[0], path=path) from exc
    if METADATA_KEY not in meta:
        raise ContractError("Parquet file has no workbench provenance metadata", path=path,
                            hint="write processed files with workbench ingest")
    return json.loads(meta[METADATA_KEY])


def read_processed(path: str | Path) -> pl.DataFrame:
    """Read a processed file (contract section 3) into a polars frame."""
    path = Path(path)
    if not path.is_file():
        raise ContractError("processed file not found", path=path, hint="run workbench ingest first")
    try:
        return pl.read_parquet(path)
    except Exception as exc:  # polars raises several kinds on damaged files
        raise ContractError(f"not a readable Parquet file: {exc}".splitlines()[0][:200], path=path) from exc


def is_up_to_date(path: str | Path, hashes: dict[str, str], params: dict[str, Any], skip_bad_runs: bool) -> bool:
    """Whether ``path`` was made from exactly these raw files and parameters by this version."""
    try:
        meta = read_provenance(path)
    except ContractError:
        return False
    return (meta.get("format") == FORMAT and meta.get("workbench_version") == __version__
            and meta.get("raw_files") == hashes and meta.get("params") == params
            and bool(meta.get("skip_bad_runs")) == bool(skip_bad_runs) and meta.get("interpolation") is None)
