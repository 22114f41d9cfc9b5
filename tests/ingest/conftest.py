"""Ingest test fixtures (the helpers live in ingest_fixtures.py, importable by a unique name)."""

from ingest_fixtures import campaign  # noqa: F401  (re-exported fixture)
