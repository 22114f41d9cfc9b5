"""Where things live: the project root, its dataset folders, pipeline parameters and the MLflow store.

The project root is the nearest folder upwards from the working directory that holds
``dvc.yaml`` or ``pyproject.toml`` (override with ``WORKBENCH_HOME``). MLflow defaults to the
project's own sqlite store ``mlflow.db`` with artifacts in ``mlartifacts/``; a tracking URI
given on the command line or in ``MLFLOW_TRACKING_URI`` (a shared server) takes precedence.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from workbench.errors import ParamsError


def project_root(start: str | Path | None = None) -> Path:
    """The workbench project folder."""
    env = os.environ.get("WORKBENCH_HOME")
    if env:
        return Path(env).resolve()
    here = Path(start or Path.cwd()).resolve()
    for p in (here, *here.parents):
        if (p / "dvc.yaml").exists() or (p / "pyproject.toml").exists():
            return p
    return here


def datasets_dir(root: Path | None = None) -> Path:
    """``<root>/datasets``."""
    return (root or project_root()) / "datasets"


def mlflow_tracking_uri(explicit: str | None = None, root: Path | None = None) -> str:
    """The tracking URI: explicit, else ``MLFLOW_TRACKING_URI``, else the project's sqlite store."""
    if explicit:
        return explicit
    env = os.environ.get("MLFLOW_TRACKING_URI")
    if env:
        return env
    return f"sqlite:///{(root or project_root()) / 'mlflow.db'}"


def mlflow_artifact_root(root: Path | None = None) -> str:
    """Artifact location of the experiments the workbench creates in the project's own store: ``<root>/mlartifacts``.

    (In general beside the sqlite store file: :func:`workbench.tracking.artifact_root`.)
    """
    return ((root or project_root()) / "mlartifacts").as_uri()


def setup_mlflow(tracking_uri: str | None = None, experiment: str | None = None) -> str:
    """Point MLflow at the store and (optionally) select/create an experiment; returns the URI.

    Kept for callers of earlier versions: the work is done by :func:`workbench.tracking.setup`
    (which also re-points a copied project's store at its own ``mlartifacts/``).
    """
    from workbench.tracking import setup

    return setup(tracking_uri, experiment)


def load_params(path: str | Path, section: str | None = None) -> Any:
    """A pipeline parameter file (YAML), or one top-level section of it, as parsed (see workbench.params).

    A relative path is taken from the working directory, else from the project root. A missing
    file, bad YAML or a missing section is a :class:`~workbench.errors.ParamsError`.
    """
    from workbench.params import read_document, suggest

    doc = read_document(path)
    if section is None:
        return doc
    if not isinstance(doc, dict) or section not in doc:
        sections = [str(k) for k in doc] if isinstance(doc, dict) else []
        raise ParamsError(f"no section '{section}' in parameter file", path=path,
                          hint=suggest(section, sections).replace("allowed:", "sections:"))
    return doc[section]


def git_commit(root: Path | None = None) -> str:
    """Current git commit of the project (``unknown`` outside a repository)."""
    import subprocess

    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root or project_root(), capture_output=True,
                             text=True, timeout=5)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"
