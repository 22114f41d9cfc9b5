"""The plan tests build on the learn tests' helpers (``learn_helpers``): that folder goes on ``sys.path``."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "learn"))
