"""campaign.toml as text (data contract section 1): the one writer the virtual lab and plan-campaign share.

Text only; whoever writes the file does so through ``workbench/atomic.py`` or its own edge.
"""

from __future__ import annotations

import json
import math
from typing import Any, Mapping, Sequence

import numpy as np

from workbench.errors import ContractError


def toml_value(v: Any) -> str:
    """A TOML value: booleans, integers, finite floats (``repr``), strings, lists; numpy scalars as Python ones."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ContractError(f"non-finite value {v} in campaign.toml", hint="the contract's numbers are finite")
        return repr(float(v))
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, np.generic):
        return toml_value(v.item())
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def campaign_toml(head: Mapping[str, Any], tables: Mapping[str, Mapping[str, Any]],
                  runs: Sequence[Mapping[str, Any]]) -> str:
    """campaign.toml: top-level keys (``date`` as a TOML date), tables, then ``[[runs]]``.

    A table's ``calibration`` (the load cell's 6 x 6 matrix) is written one row a line.
    """
    lines = []
    for k, v in head.items():
        lines.append(f"{k} = {v}" if k == "date" else f"{k} = {toml_value(v)}")
    for name, table in tables.items():
        lines.append("")
        lines.append(f"[{name}]")
        for k, v in table.items():
            if k == "calibration":
                rows = ",\n".join("  " + toml_value([float(x) for x in r]) for r in v)
                lines.append(f"{k} = [\n{rows},\n]")
            else:
                lines.append(f"{k} = {toml_value(v)}")
    for run in runs:
        lines.append("")
        lines.append("[[runs]]")
        for k, v in run.items():
            lines.append(f"{k} = {toml_value(v)}")
    return "\n".join(lines) + "\n"
