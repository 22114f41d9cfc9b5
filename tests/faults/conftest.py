"""Fault suite (issue 16): outputs never lost, one set, absurd values refused.

The fixture builders of the other test folders are imported by module name.
"""

import sys
from pathlib import Path

_TESTS = Path(__file__).resolve().parent.parent
for _sub in ("ingest", "hydro", "trials"):
    if str(_TESTS / _sub) not in sys.path:
        sys.path.insert(0, str(_TESTS / _sub))
