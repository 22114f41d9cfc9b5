"""The report's reading edge: every read of the datasets' outputs (JSON, scores.csv, figure lists).

A missing or unreadable file reads as None (or nothing): a section whose results do not exist
yet says so instead of failing the report.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def found(folder: Path, pattern: str) -> list[Path]:
    """The files under ``folder`` matching ``pattern``, sorted (none when the folder is missing)."""
    return sorted(folder.glob(pattern))


def load_json(path: Path) -> Any | None:
    """The JSON document at ``path``, or None when it is missing or not JSON."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None


def pngs(folder: Path, limit: int = 12) -> list[Path]:
    """The first ``limit`` PNG figures under ``folder`` (sorted; none when it is missing)."""
    if not folder.is_dir():
        return []
    return sorted(folder.rglob("*.png"))[:limit]


def read_scores(scores_dir: Path) -> list[dict]:
    """The rows of ``scores_dir/scores.csv`` as dicts (none when it is missing)."""
    import csv

    try:
        with open(scores_dir / "scores.csv", newline="", encoding="utf-8") as fh:
            return list(csv.DictReader(fh))
    except OSError:
        return []
