"""Find the trained leg model the pipeline uses: the registry alias first, the local model folder second.

``load_leg_model("lstm")`` resolves ``models:/<registered_model>@<alias>`` (names from
``pipelines/learn.yaml``, section ``train.tracking``; default ``models:/fed-lstm@champion``) in
the project's MLflow store (or ``MLFLOW_TRACKING_URI``). If the registry cannot be reached or
holds no such alias, it falls back to the local model folder ``datasets/models/fed-lstm`` that
``workbench train`` writes (a DVC output), with a warning line; if neither exists it fails with
a one-line ModelError. ``WORKBENCH_LSTM_URI`` (a ``models:/`` URI or a folder) overrides both.
"""

from __future__ import annotations

import os
from pathlib import Path

from workbench.errors import ModelError

DEFAULT_NAME = "fed-lstm"
DEFAULT_ALIAS = "champion"
DEFAULT_FOLDER = "models/fed-lstm"


def _defaults() -> tuple[str, str, Path]:
    from workbench.project import datasets_dir, load_params

    name, alias = DEFAULT_NAME, DEFAULT_ALIAS
    try:
        tracking = load_params("pipelines/learn.yaml", "train").get("tracking", {}) or {}
        name, alias = tracking.get("registered_model", name), tracking.get("alias", alias)
    except Exception:  # noqa: BLE001 - no parameter file: library defaults
        pass
    return name, alias, datasets_dir() / DEFAULT_FOLDER


def load_folder(path: str | Path, **info):
    """A model folder (``model.json`` + ``weights.pt``) as a LegForceModel."""
    from workbench.learn.legmodel import load_model

    return load_model(path, **info)


def load_model_uri(spec: str, *, tracking_uri: str | None = None):
    """``models:/name@alias`` or ``models:/name/version`` from the MLflow registry."""
    from workbench.learn.tracking import download_model

    path, info = download_model(spec, tracking_uri)
    return load_folder(path, **info)


def load_champion(*, tracking_uri: str | None = None, name: str | None = None, alias: str | None = None,
                  fallback: str | Path | None = None):
    """The model the pipeline uses (see the module docstring for the order of places looked in)."""
    from workbench.console import info

    override = os.environ.get("WORKBENCH_LSTM_URI")
    if override:
        return load_model_uri(override, tracking_uri=tracking_uri) if override.startswith("models:") \
            else load_folder(override, model_uri=override)
    d_name, d_alias, d_folder = _defaults()
    uri = f"models:/{name or d_name}@{alias or d_alias}"
    try:
        return load_model_uri(uri, tracking_uri=tracking_uri)
    except ModelError as exc:
        folder = Path(fallback) if fallback else d_folder
        if (folder / "model.json").is_file():
            info(f"warning: {exc.format()}; using the local model folder {folder}")
            return load_folder(folder, model_uri=str(folder))
        raise ModelError(f"no trained LSTM: {exc.fault}", hint=f"run `workbench train` (writes {folder} and "
                         f"registers {uri})") from exc
