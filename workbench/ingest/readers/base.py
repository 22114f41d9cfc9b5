"""The reader protocol and what every reader is told: the run, the facility, the expected columns."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from workbench.contract.campaign import Campaign
from workbench.contract.columns import (
    CARRIAGE_COLUMNS,
    LOADCELL_COLUMNS,
    MOTION_COLUMNS,
    MOTION_FEEDBACK_COLUMNS,
)
from workbench.errors import ContractError, DataError
from workbench.ingest.streams import Stream


@dataclass(frozen=True)
class ReadSpec:
    """What a reader needs to know beyond the file: run id, facility, feedback, calibration."""

    run: str
    facility: str
    feedback: bool = False
    calibration: np.ndarray | None = None

    @classmethod
    def for_run(cls, campaign: Campaign, run_id: str) -> "ReadSpec":
        """The spec for one run of a parsed campaign."""
        return cls(run=run_id, facility=campaign.facility,
                   feedback=bool(campaign.motion and campaign.motion.feedback),
                   calibration=campaign.loadcell.calibration_matrix())

    @property
    def controller_role(self) -> str:
        """``motion`` (water tunnel) or ``carriage`` (towing tank): the log that drives the trigger."""
        return "motion" if self.facility == "water_tunnel" else "carriage"

    def columns(self, role: str) -> tuple[str, ...]:
        """The exact columns (or MCAP message fields) of a stream, in contract order."""
        if role == "loadcell":
            return LOADCELL_COLUMNS
        if role == "motion":
            return MOTION_COLUMNS + (MOTION_FEEDBACK_COLUMNS if self.feedback else ())
        if role == "carriage":
            return CARRIAGE_COLUMNS
        raise ContractError(f"unknown stream role {role!r}", run=self.run,
                            hint="a stream's role is loadcell, motion or carriage")


class RawReader(Protocol):
    """Reads one raw file into the device streams it holds (keyed by role)."""

    path: Path

    def read(self) -> dict[str, Stream]:
        """Parse the file; raise ContractError/DataError naming file, run and fault."""
        ...


def read_raw(path: Path, run: str) -> tuple[bytes, str]:
    """A raw file's bytes and their sha256; a missing, unreadable or empty file is an error."""
    if not path.exists():
        raise ContractError("file not found", path=path, run=run, hint="check the path in campaign.toml")
    if not path.is_file():
        raise ContractError("not a regular file", path=path, run=run)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DataError(f"cannot read: {exc.strerror}", path=path, run=run) from exc
    if not data or data.isspace():
        raise DataError("empty file", path=path, run=run)
    return data, hashlib.sha256(data).hexdigest()


def header_fault(found: list[str], expected: tuple[str, ...], what: str = "column") -> str | None:
    """Describe how ``found`` names differ from the contract's ``expected`` ones (None if they match)."""
    if tuple(found) == expected:
        return None
    missing = [c for c in expected if c not in found]
    extra = [c for c in found if c not in expected]
    dup = sorted({c for c in found if found.count(c) > 1})
    parts = []
    if missing:
        parts.append(f"missing {what}(s) {', '.join(missing)}")
    if extra:
        parts.append(f"unexpected {what}(s) {', '.join(extra)}")
    if dup:
        parts.append(f"duplicated {what}(s) {', '.join(dup)}")
    if not parts:
        parts.append(f"{what}s out of order")
    return "; ".join(parts) + f"; expected {','.join(expected)}"
