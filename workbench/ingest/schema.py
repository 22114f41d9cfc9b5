"""The processed dataset's explicit Arrow schema (contract section 3) for both facilities.

One row per controller tick. Run parameters follow as columns under their manifest names, so a
row carries everything a model needs. Extra columns beyond the contract's minimum: ``cycles``
(tunnel, from the manifest, null when absent) and ``heading`` (towing).
"""

from __future__ import annotations

import pyarrow as pa

from workbench.contract.columns import (
    PROCESSED_TOWING_COLUMNS,
    PROCESSED_TUNNEL_COLUMNS,
    TUNNEL_MOTION_PARAMS,
)

#: written into the file metadata under this key (JSON)
METADATA_KEY = b"workbench"
FORMAT = "workbench/processed@1"


def _field(name: str) -> pa.Field:
    if name in ("campaign_id", "run_id", "heading"):
        return pa.field(name, pa.string(), nullable=False)
    if name == "interpolated":
        return pa.field(name, pa.bool_(), nullable=False)
    if name == "cycles":
        return pa.field(name, pa.int32(), nullable=True)
    return pa.field(name, pa.float64(), nullable=False)


TUNNEL_COLUMNS = (*PROCESSED_TUNNEL_COLUMNS, *TUNNEL_MOTION_PARAMS, "cycles")
TOWING_COLUMNS = (*PROCESSED_TOWING_COLUMNS, "heading")

TUNNEL_SCHEMA = pa.schema([_field(c) for c in TUNNEL_COLUMNS])
TOWING_SCHEMA = pa.schema([_field(c) for c in TOWING_COLUMNS])


def schema_for(facility: str) -> pa.Schema:
    """The schema of a water-tunnel or towing-tank processed file."""
    return TUNNEL_SCHEMA if facility == "water_tunnel" else TOWING_SCHEMA


def columns_for(facility: str) -> tuple[str, ...]:
    """Column names in file order."""
    return TUNNEL_COLUMNS if facility == "water_tunnel" else TOWING_COLUMNS
