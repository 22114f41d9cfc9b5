"""Find the trained leg model the pipeline uses: the registry alias first, the local model folder second.

``load_leg_model("lstm")`` resolves ``models:/<registered_model>@<alias>`` (names from
``pipelines/learn.yaml``, section ``train.tracking``; default ``models:/fed-lstm@champion``) in
the project's MLflow store (or ``MLFLOW_TRACKING_URI``). If the registry cannot be reached or
holds no such alias, it falls back to the local model folder ``datasets/models/fed-lstm`` that
``workbench train`` writes (a DVC output), with a warning line; if neither exists it fails with
a one-line ModelError. ``WORKBENCH_LSTM_URI`` (a ``models:/`` URI or a folder) overrides both.

A saved model folder (``model.json`` + ``weights.pt``, what ``workbench train --out`` writes and
DVC tracks) also loads by its path: ``load_leg_model("datasets/models/fed-lstm-16")``. Pipeline
stages name their model that way (issue 15.1): a path is a DVC dep, a registry alias is not.
Whatever way a model was found, its ``describe()`` says where from: ``model_uri`` and
``model_version`` (and ``run_id``) for the registry, ``model_path`` for a folder (read by
:func:`workbench.gait.export.model_source`).
"""

from __future__ import annotations

import os
from pathlib import Path

from workbench.errors import ModelError, ModelLoadError

DEFAULT_NAME = "fed-lstm"
DEFAULT_ALIAS = "champion"
DEFAULT_FOLDER = "models/fed-lstm"


def _defaults() -> tuple[str, str, Path]:
    from workbench.learn.config import TrackingSettings
    from workbench.params import build, read_section
    from workbench.project import datasets_dir

    name, alias = DEFAULT_NAME, DEFAULT_ALIAS
    try:
        train, source = read_section("pipelines/learn.yaml", "train")
        tracking = build(TrackingSettings, train.get("tracking"), key="train.tracking", path=source)
        name, alias = tracking.registered_model, tracking.alias
    except Exception:  # noqa: BLE001 - no parameter file: library defaults
        pass
    return name, alias, datasets_dir() / DEFAULT_FOLDER


def load_folder(path: str | Path, **info):
    """A model folder (``model.json`` + ``weights.pt``) as a LegForceModel."""
    from workbench.learn.legmodel import load_model

    return load_model(path, **info)


def load_path(path: str | Path, **kwargs):
    """A path to a saved learned model (its folder, or the folder's ``model.json``); None if it is not one.

    The path-loader hook of :func:`workbench.hydro.legmodel.load_leg_model`: other kinds of saved
    models (e.g. augmented models) answer for their own paths. A folder that says it is a learned
    model but does not load (torn weights, a foreign schema) fails with a one-line ModelLoadError.
    The folder is read through :mod:`workbench.learn.legmodel` (learn's edge for saved models).
    """
    from workbench.learn.legmodel import MODEL_SCHEMA, read_model_head

    found = read_model_head(path)
    if found is None:
        return None
    folder, head = found
    if not str(head.get("schema", "")).startswith("workbench/learned-leg-model@"):
        return None
    if head.get("schema") != MODEL_SCHEMA:
        raise ModelLoadError(f"unknown model schema {head.get('schema')!r}", path=folder / "model.json",
                             hint=f"expected {MODEL_SCHEMA}")
    return load_folder(folder, model_path=str(path), **kwargs)


def load_model_uri(spec: str, *, tracking_uri: str | None = None):
    """``models:/name@alias`` or ``models:/name/version`` from the MLflow registry.

    A version is an MLflow pyfunc model whose artifact ``leg_model`` is the model folder
    (:mod:`workbench.learn.pyfunc`), or, if it was registered before models were MLflow models,
    the plain folder itself; both load (:func:`workbench.learn.legmodel.mlflow_model_folder`).
    """
    from workbench.learn.legmodel import mlflow_model_folder
    from workbench.tracking import download_model

    path, info = download_model(spec, tracking_uri)
    return load_folder(mlflow_model_folder(path), **info)


def load_champion(*, tracking_uri: str | None = None, name: str | None = None, alias: str | None = None,
                  fallback: str | Path | None = None):
    """The model the pipeline uses (see the module docstring for the order of places looked in)."""
    from workbench.console import info

    override = os.environ.get("WORKBENCH_LSTM_URI")
    if override:
        return load_model_uri(override, tracking_uri=tracking_uri) if override.startswith("models:") \
            else load_folder(override, model_uri=override, model_path=override)
    d_name, d_alias, d_folder = _defaults()
    uri = f"models:/{name or d_name}@{alias or d_alias}"
    try:
        return load_model_uri(uri, tracking_uri=tracking_uri)
    except ModelError as exc:
        folder = Path(fallback) if fallback else d_folder
        if (folder / "model.json").is_file():
            info(f"warning: {exc.format()}; using the local model folder {folder}")
            return load_folder(folder, model_uri=str(folder), model_path=str(folder))
        raise ModelError(f"no trained LSTM: {exc.fault}", hint=f"run `workbench train` (writes {folder} and "
                         f"registers {uri})") from exc
