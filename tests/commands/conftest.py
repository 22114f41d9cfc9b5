"""CLI tests (one file per verb or verb group): the fixture builders of the package folders, imported by name.

``ingest_fixtures`` (small contract campaigns with known truth), ``towing_fixture`` (a raw towing
campaign from the paper's drag) and the gait folder's contract check live beside the package tests
that own them; this folder puts those folders on ``sys.path`` and re-exports the ``campaign`` fixture.
"""

import sys
from pathlib import Path

_TESTS = Path(__file__).resolve().parent.parent
for _sub in ("ingest", "hydro", "gait"):
    if str(_TESTS / _sub) not in sys.path:
        sys.path.insert(0, str(_TESTS / _sub))

from ingest_fixtures import campaign  # noqa: E402,F401  (re-exported fixture)
