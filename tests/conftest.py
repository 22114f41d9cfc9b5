"""Shared test setup: headless plotting, quiet threads, an isolated MLflow store per test session."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")
