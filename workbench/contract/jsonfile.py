"""Reading a JSON file of the data contract (drag.json, gait files): one message for a missing or broken file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from workbench.errors import ContractError


def read_json(path: str | Path, what: str = "file", *, hint: str | None = None) -> Any:
    """The parsed JSON document at ``path``.

    A missing file is a :class:`ContractError` "``what`` not found" (with ``hint``, e.g. the verb
    that writes it); a file that is not UTF-8 JSON is one naming the parser's fault.
    """
    p = Path(path)
    try:
        return json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ContractError(f"{what} not found", path=p, hint=hint) from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ContractError(f"not valid JSON: {exc}", path=p) from None
