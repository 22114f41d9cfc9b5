"""Raw campaign folders (data contract v1) in, one validated processed Parquet file per campaign out.

Public API::

    result = ingest_campaign("datasets/raw/demo-tunnel")          # IngestResult(frame, quality, ...)
    write_processed(result, "datasets/processed/demo-tunnel.parquet")
    frame = read_processed("datasets/processed/demo-tunnel.parquet")
    meta = read_provenance("datasets/processed/demo-tunnel.parquet")

See docs/ingest.md for the order of operations, the parameters and the metadata.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

from workbench.contract.campaign import check_manifest
from workbench.ingest.campaign import IngestResult, as_params, ingest_campaign
from workbench.ingest.params import IngestParams, IngestSettings
from workbench.ingest.provenance import (
    campaign_hashes,
    is_up_to_date,
    quality_path,
    read_processed,
    read_provenance,
    sync_quality,
    write_processed,
)

__all__ = [
    "IngestParams",
    "IngestSettings",
    "IngestResult",
    "ingest_campaign",
    "ingest_to_file",
    "quality_path",
    "read_processed",
    "read_provenance",
    "sync_quality",
    "up_to_date",
    "write_processed",
]


def up_to_date(campaign_dir: str | Path, out: str | Path, params: IngestSettings | Mapping[str, Any] | None = None,
               skip_bad_runs: bool = False) -> bool:
    """Whether ``out`` already holds this campaign's raw files processed with these parameters."""
    out = Path(out)
    if not out.is_file():
        return False
    camp, errors = check_manifest(campaign_dir, as_params(params).limits)
    if camp is None or any(e.run is None for e in errors):
        return False
    return is_up_to_date(out, campaign_hashes(camp), as_params(params).recorded(), skip_bad_runs)


def ingest_to_file(campaign_dir: str | Path, out: str | Path, *,
                   params: IngestSettings | Mapping[str, Any] | None = None, skip_bad_runs: bool = False,
                   force: bool = False, progress=None) -> IngestResult | None:
    """Ingest and write atomically; return None (nothing done) when ``out`` is already up to date.

    ``out`` inside a raw campaign folder is refused before any work. When ``out`` is up to date its
    quality report is brought in line with the Parquet file's metadata (:func:`sync_quality`).
    """
    from workbench.atomic import check_not_raw

    check_not_raw(out)
    if not force and up_to_date(campaign_dir, out, params, skip_bad_runs):
        sync_quality(out)
        return None
    result = ingest_campaign(campaign_dir, params=params, skip_bad_runs=skip_bad_runs, progress=progress)
    write_processed(result, out)
    return result
