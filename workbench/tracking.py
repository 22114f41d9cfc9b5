"""MLflow in one place: the store, run names, tags, parameters, metrics, runs, the model registry.

Every package that records to MLflow (``learn``: train, tune, evaluate; ``gait``: optimize;
``diagnose``) hands this module plain dicts; nothing else talks to MLflow's logging API.

* **Store** (:func:`setup`): the project's sqlite store ``mlflow.db`` unless a tracking URI is
  given (``--tracking-uri``, ``MLFLOW_TRACKING_URI``: a server). Experiments the workbench
  creates in a sqlite store keep their artifacts in ``mlartifacts/`` **beside the store file**.
  MLflow writes absolute artifact paths into the store, so a copied project (``cp -r``, or a clone
  given a copy of ``mlflow.db`` and ``mlartifacts/``) would log into the original's folder:
  :func:`relocate_store` notices a store whose workbench experiments point at another folder's
  ``mlartifacts`` and re-points them (and the runs, logged models and model versions whose files
  were copied along) at the store's own folder, once per process, before anything is logged.
* **Run names** (:func:`run_name`): ``<verb> <model> <campaigns> @<short commit>``, e.g.
  ``train fed-lstm demo-tunnel @a1b2c3d``; a run made by a DVC stage starts with
  ``dvc:<stage>`` instead (``dvc:train fed-lstm demo-tunnel @a1b2c3d``), so a pipeline run and a
  manual one never share a name.
* **Tags** (:func:`run_tags`), the same on every run: ``kind`` (train, trial, tune, evaluate,
  optimize, diagnose, diagnose-trajectory), ``campaign`` (campaign ids joined by ``+``),
  ``git_commit``, ``dvc_stage`` (the stage, or ``manual``), ``dvc_exp`` inside ``dvc exp run``,
  and ``state`` when the run ends (``complete``, ``pruned``, ``failed``, ``interrupted``: MLflow's
  own status can only say FINISHED, FAILED or KILLED).
* **Parameters** (:func:`log_params`): nested dicts flattened to dotted keys and logged in
  batches of MLflow's 100 per call, so nothing is cut; a value longer than MLflow's limit (6000
  characters) is cut with the marker :data:`TRUNCATED` and the whole document is logged as the
  artifact ``params.json``.
* **Metrics** (:func:`log_metrics`): nested numeric dicts flattened, non-finite values left out,
  batches of 1000.
* **Registry** (:func:`register_model`): a run's logged MLflow model (or, for runs of older
  versions, its ``model/`` folder) becomes a version of a registered model, with an alias.
"""

from __future__ import annotations

import json
import math
import os
import re
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Mapping

from workbench.errors import ModelLoadError

#: the folder beside a sqlite store that holds its artifacts
ARTIFACTS_DIR = "mlartifacts"
#: the artifact path of a run's model (MLflow model name, or the plain folder of older runs)
MODEL_ARTIFACT = "model"
#: run tag naming the MLflow logged model (``m-...``) of a training run
MODEL_ID_TAG = "model_id"
#: appended to a parameter value cut at MLflow's length limit
TRUNCATED = "...[truncated: full value in params.json]"
#: where the full parameter document goes (run artifact)
PARAMS_DOCUMENT = "params.json"

_PARAMS_PER_BATCH = 100
_METRICS_PER_BATCH = 1000
_KEY_MAX = 250
_CHECKED_STORES: set[str] = set()


# -- the store ---------------------------------------------------------------------------------
def tracking_uri(explicit: str | None = None) -> str:
    """Explicit, else ``MLFLOW_TRACKING_URI``, else the project's sqlite store ``<root>/mlflow.db``."""
    from workbench.project import mlflow_tracking_uri

    return mlflow_tracking_uri(explicit)


def sqlite_path(uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` tracking URI (None for anything else, or an in-memory store)."""
    if not uri.startswith("sqlite:///"):
        return None
    path = uri[len("sqlite:///"):].split("?", 1)[0]
    if not path or path == ":memory:":
        return None
    return Path(path).resolve()


def artifact_root(uri: str) -> str | None:
    """Where a store's experiments keep artifacts: ``<store folder>/mlartifacts`` for sqlite; None (the server's) else."""
    db = sqlite_path(uri)
    return (db.parent / ARTIFACTS_DIR).as_uri() if db is not None else None


def setup(tracking_uri_: str | None = None, experiment: str | None = None) -> str:
    """Point MLflow at the store, re-point a copied store, select/create ``experiment``; returns the URI.

    MLflow's INFO lines are quietened. An experiment created here in a sqlite store keeps its
    artifacts beside the store (:func:`artifact_root`).
    """
    import logging

    import mlflow

    logging.getLogger("mlflow").setLevel(logging.WARNING)
    uri = use_store(tracking_uri_)
    if experiment:
        if mlflow.get_experiment_by_name(experiment) is None:
            kwargs: dict[str, Any] = {}
            root = artifact_root(uri)
            if root:
                kwargs["artifact_location"] = root
            # MLflow 3's UI opens GenAI pages for experiments of unknown kind; ours are model training
            kwargs["tags"] = {"mlflow.experimentKind": "custom_model_development"}
            try:
                mlflow.create_experiment(experiment, **kwargs)
            except Exception:  # noqa: BLE001 - another process created it first
                pass
        mlflow.set_experiment(experiment)
    return uri


def use_store(tracking_uri_: str | None = None) -> str:
    """Point MLflow at the store (explicit, env, or the project's) after re-pointing a copied sqlite store; the URI.

    The store is checked once per process (:func:`relocate_store`); reading a registered model
    goes through here too, so a copied project loads its own files even before it logs anything.
    """
    import mlflow

    uri = tracking_uri(tracking_uri_)
    mlflow.set_tracking_uri(uri)
    db = sqlite_path(uri)
    if db is not None and str(db) not in _CHECKED_STORES:
        relocate_store(uri)
        _CHECKED_STORES.add(str(db))
    return uri


def _uri_path(uri: str) -> Path:
    from urllib.parse import unquote, urlparse

    return Path(unquote(urlparse(uri).path))


def _foreign_artifacts(location: str | None, home: str) -> bool:
    """A workbench experiment location (``file://.../mlartifacts``) that is not this store's own."""
    if not location or not location.startswith("file://"):
        return False
    loc = location.rstrip("/")
    return loc != home and loc.endswith("/" + ARTIFACTS_DIR)


def relocate_store(uri: str) -> dict[str, int]:
    """Re-point a copied sqlite store's artifact paths at its own ``mlartifacts/``; returns the rows changed per table.

    MLflow stores absolute artifact locations (experiments, runs, logged models, model versions).
    After ``cp -r project copy``, ``copy/mlflow.db`` still names ``project/mlartifacts``: runs
    logged from the copy would land in the original's folder, and models would load from there.
    Here every experiment located in some other folder's ``mlartifacts`` gets this store's own
    ``mlartifacts`` (new runs go there), and each run, logged model and model version under the
    old location is re-pointed when its files were copied along (they exist under the new folder)
    or no longer exist at the old place. Rows whose files exist only at the old place (a store
    shared, not copied) keep their paths. One transaction; idempotent; no-op for other stores.
    """
    import sqlite3

    db = sqlite_path(uri)
    if db is None or not db.is_file():
        return {}
    home = (db.parent / ARTIFACTS_DIR).as_uri()
    con = sqlite3.connect(str(db), timeout=60, isolation_level=None)
    try:
        changed = _relocate(con, home)
    except BaseException:
        if con.in_transaction:
            con.execute("ROLLBACK")
        raise
    finally:
        con.close()
    if changed:
        from workbench.console import info

        info(f"MLflow store {db} was copied or moved: artifact paths now point at {_uri_path(home)} "
             f"({', '.join(f'{n} {t}' for t, n in sorted(changed.items()))})")
    return changed


#: (table, column) of the artifact paths under an experiment's location
_ARTIFACT_COLUMNS = (("runs", "artifact_uri"), ("logged_models", "artifact_location"),
                     ("model_versions", "storage_location"), ("model_versions", "source"))


def _relocate(con, home: str) -> dict[str, int]:
    """In one transaction, re-point every foreign experiment and the paths under it at ``home``; rows changed per table."""
    tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    if "experiments" not in tables:
        return {}
    if not any(_foreign_artifacts(loc, home) for (loc,) in con.execute("SELECT artifact_location FROM experiments")):
        return {}
    con.execute("BEGIN IMMEDIATE")  # another process relocating at the same moment waits, then finds nothing
    olds = sorted({loc.rstrip("/") for (loc,) in con.execute("SELECT artifact_location FROM experiments")
                   if _foreign_artifacts(loc, home)})
    changed: dict[str, int] = {}
    for old in olds:
        cur = con.execute("UPDATE experiments SET artifact_location = ? WHERE rtrim(artifact_location, '/') = ?",
                          (home, old))
        changed["experiments"] = changed.get("experiments", 0) + cur.rowcount
        for table, col in _ARTIFACT_COLUMNS:
            if table in tables:
                _repoint_paths(con, table, col, old, home, changed)
    con.execute("COMMIT")
    return changed


def _repoint_paths(con, table: str, col: str, old: str, home: str, changed: dict[str, int]) -> None:
    """Re-point ``table.col`` paths under ``old`` at ``home`` where the files were copied along or are gone."""
    prefix = old + "/"
    rows = con.execute(f"SELECT rowid, {col} FROM {table} WHERE substr({col}, 1, ?) = ?",  # noqa: S608
                       (len(prefix), prefix)).fetchall()
    for rowid, value in rows:
        new = home + value[len(old):]
        if _uri_path(new).exists() or not _uri_path(value).exists():
            con.execute(f"UPDATE {table} SET {col} = ? WHERE rowid = ?", (new, rowid))  # noqa: S608
            changed[table] = changed.get(table, 0) + 1


# -- names and tags ----------------------------------------------------------------------------
def dvc_stage_name(explicit: str | None = None) -> str:
    """The DVC stage a run belongs to: explicit, else ``DVC_STAGE`` (set by ``dvc repro``), else ``manual``."""
    return explicit or os.environ.get("DVC_STAGE") or "manual"


def campaign_label(campaigns) -> str:
    """Campaign ids joined by ``+`` (order kept, duplicates dropped); ``unknown`` when there are none."""
    if isinstance(campaigns, str):
        campaigns = [campaigns]
    ids = [str(c) for c in dict.fromkeys(campaigns or ()) if c]
    return "+".join(ids) or "unknown"


def run_name(verb: str, model: str | None = None, campaigns=(), dvc_stage: str | None = None,
             commit: str | None = None) -> str:
    """``<verb> <model> <campaigns> @<short commit>``; a DVC stage's run starts ``dvc:<stage>`` instead of the verb.

    >>> run_name("train", "fed-lstm", ["demo-tunnel"], "manual", "a1b2c3d4e5")
    'train fed-lstm demo-tunnel @a1b2c3d'
    >>> run_name("train", "fed-lstm", ["demo-tunnel"], "train", "a1b2c3d4e5")
    'dvc:train fed-lstm demo-tunnel @a1b2c3d'
    >>> run_name("trial 003", "fed-lstm-demo", ["demo-tunnel"], "tune", "a1b2c3d4e5")
    'dvc:tune trial 003 fed-lstm-demo demo-tunnel @a1b2c3d'
    """
    from workbench.project import git_commit

    stage = dvc_stage_name(dvc_stage)
    if stage == "manual":
        head = verb
    elif verb.split(" ", 1)[0] == stage:
        head = f"dvc:{verb}"
    else:
        head = f"dvc:{stage} {verb}"
    commit = commit or git_commit()
    short = commit[:7] if commit and commit != "unknown" else "nogit"
    label = campaign_label(campaigns)
    if label.count("+") > 2:
        ids = label.split("+")
        label = f"{'+'.join(ids[:2])}+{len(ids) - 2} more"
    parts = [head, model or "", label, f"@{short}"]
    return " ".join(p for p in parts if p)[:240]


def run_tags(*, kind: str, campaigns=(), dvc_stage: str | None = None, commit: str | None = None,
             **extra: Any) -> dict[str, str]:
    """The tags every run carries: ``kind``, ``campaign``, ``git_commit``, ``dvc_stage`` (+ ``dvc_exp``) and ``extra``.

    ``None`` values in ``extra`` are left out; everything else becomes a string.
    """
    from workbench.project import git_commit

    tags = {"kind": kind, "campaign": campaign_label(campaigns), "git_commit": commit or git_commit(),
            "dvc_stage": dvc_stage_name(dvc_stage)}
    if os.environ.get("DVC_EXP_NAME"):
        tags["dvc_exp"] = os.environ["DVC_EXP_NAME"]
    tags.update({k: str(v) for k, v in extra.items() if v is not None})
    return tags


# -- parameters and metrics --------------------------------------------------------------------
def flatten(d: Mapping[str, Any], prefix: str = "", sep: str = ".") -> dict[str, Any]:
    """Nested mappings -> ``{"model.hidden_size": 64, ...}`` (leaves unchanged; an empty mapping stays a leaf)."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{sep}{k}" if prefix else str(k)
        if isinstance(v, Mapping) and v:
            out.update(flatten(v, key, sep))
        else:
            out[key] = v
    return out


def _key(name: str) -> str:
    """A valid MLflow parameter or metric key: other characters become ``_``; over 250 characters, cut + a hash."""
    import hashlib

    key = re.sub(r"[^/\w.\- :]", "_", name).strip("/") or "_"
    if len(key) > _KEY_MAX:
        key = key[:_KEY_MAX - 11] + "~" + hashlib.sha1(name.encode()).hexdigest()[:10]
    return key


def _param_value(v: Any) -> str:
    if isinstance(v, (list, tuple, Mapping)):
        try:
            return json.dumps(v, default=str)
        except (TypeError, ValueError):
            return str(v)
    return str(v)


def param_values(params: Mapping[str, Any]) -> tuple[dict[str, str], list[str]]:
    """``(flat params as MLflow accepts them, keys whose value had to be truncated)``."""
    from mlflow.utils.validation import MAX_PARAM_VAL_LENGTH

    out: dict[str, str] = {}
    cut: list[str] = []
    for k, v in flatten(params).items():
        s = _param_value(v)
        if len(s) > MAX_PARAM_VAL_LENGTH:
            s = s[:MAX_PARAM_VAL_LENGTH - len(TRUNCATED)] + TRUNCATED
            cut.append(k)
        out[_key(k)] = s
    return out, cut


def log_params(params: Mapping[str, Any], *, run_id: str | None = None,
               document: str | None = PARAMS_DOCUMENT) -> dict[str, str]:
    """Log every (flattened) parameter, in batches of 100; the whole document as the artifact ``document``.

    Returns what was logged. Values over MLflow's length limit end in :data:`TRUNCATED`; the
    document keeps them whole.
    """
    import mlflow
    from mlflow.entities import Param

    run_id = run_id or mlflow.active_run().info.run_id
    flat, _cut = param_values(params)
    client = mlflow.MlflowClient()
    items = [Param(k, v) for k, v in flat.items()]
    for i in range(0, len(items), _PARAMS_PER_BATCH):
        client.log_batch(run_id, params=items[i:i + _PARAMS_PER_BATCH])
    if document:
        client.log_text(run_id, json.dumps(params, indent=2, default=str) + "\n", document)
    return flat


def flat_metrics(d: Mapping[str, Any], prefix: str = "", sep: str = "_") -> dict[str, float]:
    """Nested numeric dict -> flat metric names (non-numbers, booleans, NaN and infinities left out)."""
    out: dict[str, float] = {}
    for k, v in flatten(d, prefix, sep).items():
        if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v):
            out[_key(k)] = float(v)
    return out


def log_metrics(metrics: Mapping[str, Any], *, step: int | None = None, run_id: str | None = None,
                sep: str = ".") -> dict[str, float]:
    """Log a (nested) dict of numbers in batches of 1000; returns what was logged."""
    import time

    import mlflow
    from mlflow.entities import Metric

    run_id = run_id or mlflow.active_run().info.run_id
    flat = flat_metrics(metrics, sep=sep)
    now = int(time.time() * 1000)
    items = [Metric(k, v, now, step or 0) for k, v in flat.items()]
    client = mlflow.MlflowClient()
    for i in range(0, len(items), _METRICS_PER_BATCH):
        client.log_batch(run_id, metrics=items[i:i + _METRICS_PER_BATCH])
    return flat


def log_metric_series(series: Mapping[str, list[tuple[int, float]]], *, run_id: str | None = None) -> None:
    """Log ``{name: [(step, value), ...]}`` (e.g. a hypervolume per generation) in batches of 1000."""
    import time

    import mlflow
    from mlflow.entities import Metric

    run_id = run_id or mlflow.active_run().info.run_id
    now = int(time.time() * 1000)
    items = [Metric(_key(name), float(v), now, int(step)) for name, points in series.items()
             for step, v in points if isinstance(v, (int, float)) and math.isfinite(v)]
    client = mlflow.MlflowClient()
    for i in range(0, len(items), _METRICS_PER_BATCH):
        client.log_batch(run_id, metrics=items[i:i + _METRICS_PER_BATCH])


# -- runs --------------------------------------------------------------------------------------
def end_state(exc: BaseException | None) -> tuple[str, str]:
    """``(MLflow status, state tag)`` for a run that ended with ``exc`` (None: it completed)."""
    if exc is None:
        return "FINISHED", "complete"
    name = type(exc).__name__
    if name == "TrialPruned":
        return "KILLED", "pruned"
    if isinstance(exc, KeyboardInterrupt):
        return "KILLED", "interrupted"
    return "FAILED", "failed"


@contextmanager
def tracked_run(*, name: str, tags: Mapping[str, str], experiment: str | None = None,
                tracking_uri_: str | None = None, parent_run_id: str | None = None,
                params: Mapping[str, Any] | None = None) -> Iterator[Any]:
    """An MLflow run: set up the store, start (nested under ``parent_run_id`` or an active run), end with a state.

    On leaving, the run is tagged ``state`` = complete | pruned (an Optuna trial) | interrupted |
    failed, and ends FINISHED, KILLED (pruned, interrupted) or FAILED.
    """
    import mlflow

    setup(tracking_uri_, experiment)
    nested = parent_run_id is not None or mlflow.active_run() is not None
    run = mlflow.start_run(run_name=name, tags=dict(tags), nested=nested, parent_run_id=parent_run_id)
    exc: BaseException | None = None
    try:
        if params:
            log_params(params, run_id=run.info.run_id)
        yield run
    except BaseException as e:
        exc = e
        raise
    finally:
        status, state = end_state(exc)
        try:
            mlflow.MlflowClient().set_tag(run.info.run_id, "state", state)
            if exc is not None and state == "pruned":
                mlflow.MlflowClient().set_tag(run.info.run_id, "state_detail", str(exc)[:500])
        finally:
            mlflow.end_run(status=status)


def log_artifacts(paths=(), folders: Mapping[str, str | Path] | None = None, *, under: str | None = None,
                  run_id: str | None = None) -> None:
    """Log files (at the run's root, or in ``under``) and folders (``{artifact_path: folder}``; ``""``: the root)."""
    import mlflow

    run_id = run_id or mlflow.active_run().info.run_id
    client = mlflow.MlflowClient()
    for p in paths:
        client.log_artifact(run_id, str(p), artifact_path=under)
    for where, folder in (folders or {}).items():
        client.log_artifacts(run_id, str(folder), artifact_path=where or None)


# -- the registry ------------------------------------------------------------------------------
def model_uri(name: str, alias: str = "champion") -> str:
    """``models:/<name>@<alias>``."""
    return f"models:/{name}@{alias}"


def retry_race(call, errors: tuple[type[BaseException], ...] | None = None, attempts: int = 6):
    """``call()``, retried with a random back-off when a shared store refuses it because a concurrent writer won.

    MLflow's SQL registry sets an alias by select-then-insert, so two writers of one alias can
    both insert and one fails on the primary key; Optuna's first schema creation on an empty
    database races the same way. On the retry the winner's row or table exists. ``errors``
    defaults to MLflow's exceptions.
    """
    import random
    import time

    if errors is None:
        from mlflow.exceptions import MlflowException

        errors = (MlflowException,)
    for attempt in range(attempts):
        try:
            return call()
        except errors:
            if attempt == attempts - 1:
                raise
            time.sleep(0.2 + random.random() * (0.5 + attempt))
    raise AssertionError("unreachable")


def version_of_run(client, name: str, run_id: str):
    """The oldest version of registered model ``name`` made from run ``run_id``, or None."""
    found = client.search_model_versions(f"name = '{name}' and run_id = '{run_id}'")
    return min(found, key=lambda v: int(v.version)) if found else None


def logged_model_id(client, run) -> str | None:
    """The MLflow logged model of a run (its ``model_id`` tag, else MLflow's record of the run's outputs)."""
    mid = run.data.tags.get(MODEL_ID_TAG)
    if mid:
        return mid
    outputs = getattr(run, "outputs", None)
    for out in getattr(outputs, "model_outputs", None) or []:
        return out.model_id
    return None


def register_model(run, name: str, alias: str | None, tags: Mapping[str, str] | None = None,
                   description: str = "Learned leg force models (FED-LSTM and variants); load with "
                                      "mlflow.pyfunc.load_model or workbench.hydro.legmodel.load_leg_model") -> str:
    """Register the run's model as a version of ``name`` (through MLflow's API) and point ``alias`` at it.

    The run's logged MLflow model (``mlflow.pyfunc``, what ``workbench train`` logs) is registered
    as MLflow's ``register_model("models:/<model id>")`` does (``create_model_version`` with the
    model id), so the registry links version, logged model and run; a run of an older version without one registers its ``model/`` folder.
    Safe when several machines do it at once on one shared store (tune workers finishing together):
    a run keeps one version (the oldest, when two machines registered it at the same moment), and
    a registry write that loses a race on the store's unique keys is retried.
    """
    from mlflow import MlflowClient

    client = MlflowClient()
    try:
        client.get_registered_model(name)
    except Exception:  # noqa: BLE001 - not there yet (another process may race us: tolerate "exists")
        try:
            client.create_registered_model(name, description=description)
        except Exception:  # noqa: BLE001
            pass
    run_id = run.info.run_id
    mv = version_of_run(client, name, run_id)
    if mv is None:
        mid = logged_model_id(client, run)
        if mid:  # what mlflow.register_model("models:/<id>") does, without its lines on stderr
            mine = retry_race(lambda: client.create_model_version(name, source=f"models:/{mid}", run_id=run_id,
                                                                  tags=dict(tags or {}), model_id=mid))
        else:
            mine = retry_race(lambda: client.create_model_version(
                name, source=f"{run.info.artifact_uri}/{MODEL_ARTIFACT}", run_id=run_id, tags=dict(tags or {})))
        # another machine may have registered the same run a moment before: keep its (older) version
        mv = version_of_run(client, name, run_id) or mine
        if mv.version != mine.version:
            client.delete_model_version(name, mine.version)
    if alias:
        retry_race(lambda: client.set_registered_model_alias(name, alias, mv.version))
    return str(mv.version)


def resolve_version(uri: str, tracking_uri_: str | None = None):
    """The registry version a ``models:/name@alias`` or ``models:/name/version`` URI names (MLflow ModelVersion)."""
    from mlflow import MlflowClient

    use_store(tracking_uri_)
    body = uri[len("models:/"):]
    client = MlflowClient()
    if "@" in body:
        name, alias = body.split("@", 1)
        return client.get_model_version_by_alias(name, alias)
    name, version = body.rsplit("/", 1)
    return client.get_model_version(name, version)


def download_model(uri: str, tracking_uri_: str | None = None) -> tuple[Path, dict]:
    """Resolve a ``models:/name@alias`` (or ``models:/name/version``) URI to a local folder and its version info.

    The folder is the version's artifacts as logged: an MLflow model (``MLmodel``, ...) for
    versions logged by this workbench, a plain model folder for older ones. Read through the
    version's storage URI: a ``models:/`` download of a local store hands back the store's own
    folder and writes a ``registered_model_meta`` file into it, so loading a model changed the store.
    """
    import mlflow

    try:
        mv = resolve_version(uri, tracking_uri_)
        where = mlflow.MlflowClient().get_model_version_download_uri(mv.name, mv.version)
        path = mlflow.artifacts.download_artifacts(artifact_uri=where)
    except Exception as exc:  # noqa: BLE001 - MLflow raises many kinds; one line for the user
        raise ModelLoadError(f"cannot load {uri} from {mlflow.get_tracking_uri()} ({type(exc).__name__}: "
                             f"{str(exc).splitlines()[0][:160] if str(exc) else ''})",
                             hint="train first (workbench train) or pass --tracking-uri") from exc
    return Path(path), {"model_uri": uri, "model_version": str(mv.version), "run_id": mv.run_id}
