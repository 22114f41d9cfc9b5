"""``train(cfg) -> (metrics, objects)``: one configuration, from processed Parquet to a scored, saved model.

The one function the CLI (``workbench train``), the Optuna objective and the tests call. It reads
the data (or takes prepared data, so a search reads it once per worker), splits it by parameter
set, trains with Lightning, keeps the best-validation weights, scores the model and the EF on
the held-out test sets through the leg force model interface, and
records everything in MLflow (and registers the model) when tracking is enabled.

It writes no file: the model card (the model folder's files: ``model.json``, ``weights.pt``,
``config.json``, ``split.json``, ``metrics.json``, ``history.csv``, ``learning_curve.png``) comes
back as bytes in ``objects["card"]`` (:func:`model_card`), and ``workbench train`` writes it to
``--out`` through ``workbench/atomic.py`` as one set (:func:`workbench.commands.train.write_model_card`).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import time
from contextlib import contextmanager
from datetime import timedelta
from typing import Callable, Sequence

from workbench.learn.config import LearnSettings
from workbench.threads import apply_torch_threads

#: extra test metrics logged per channel
_LOG_CHANNELS = ("fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm")


def _quiet_lightning() -> None:
    for name in ("lightning.pytorch", "lightning.fabric", "lightning"):
        logging.getLogger(name).setLevel(logging.WARNING)
    import warnings

    warnings.filterwarnings("ignore", message=".*does not have many workers.*")
    warnings.filterwarnings("ignore", message=".*LeafSpec.*")


@contextmanager
def _mlflow_run(cfg: LearnSettings, tags: dict, run_name: str, parent_run_id: str | None):
    """An MLflow run (:func:`workbench.tracking.tracked_run`), or None when tracking is off.

    A pruned Optuna trial ends KILLED and tagged ``state=pruned``, Ctrl-C KILLED ``interrupted``,
    any other error FAILED ``failed``, else FINISHED ``complete``.
    """
    if not cfg.tracking.enabled:
        yield None
        return
    from workbench.tracking import tracked_run

    with tracked_run(name=run_name, tags=tags, experiment=cfg.tracking.experiment,
                     tracking_uri_=cfg.tracking.tracking_uri, parent_run_id=parent_run_id) as run:
        yield run


def default_run_name(cfg: LearnSettings, campaigns=(), kind: str = "train", extra_tags: dict | None = None) -> str:
    """The run's name unless the configuration gives one (``tracking.run_name``).

    ``train fed-lstm demo-tunnel @a1b2c3d`` (``dvc:train ...`` from a DVC stage) for training,
    ``trial 003 <study> <campaigns> @<commit>`` for a tune trial: :func:`workbench.tracking.run_name`.
    """
    from workbench.tracking import run_name

    if cfg.tracking.run_name:
        return cfg.tracking.run_name
    extra = extra_tags or {}
    if kind == "trial" and "trial" in extra:
        return run_name(f"trial {int(extra['trial']):03d}", extra.get("study"), campaigns, cfg.tracking.dvc_stage)
    return run_name(kind, cfg.tracking.registered_model, campaigns, cfg.tracking.dvc_stage)


def train(cfg: LearnSettings, *, prepared=None, callbacks: Sequence = (), report: Callable[[str], None] | None = None,
          parent_run_id: str | None = None, extra_tags: dict | None = None, kind: str = "train",
          log_model: bool = True, score_test: bool = True) -> tuple[dict, dict]:
    """Train one configuration; returns ``(metrics, objects)``.

    ``prepared``: a :class:`~workbench.learn.datamodule.PreparedData` to reuse (else read
    ``cfg.data.paths``); ``callbacks``: extra Lightning callbacks (e.g. Optuna pruning);
    ``report``: where per-epoch lines go; ``parent_run_id``: MLflow parent (tune trials);
    ``score_test``: score on the held-out test sets (a search leaves them alone).
    ``objects`` holds ``model`` (the :class:`LegForceModel`), ``module``, ``datamodule``,
    ``prepared``, ``history``, ``card`` (the model folder's files as bytes, :func:`model_card`;
    with the learning curve when ``cfg.model_dir`` names a folder to write) and, when tracked,
    ``run_id`` and ``model_version``. Nothing is written to disk: the caller writes ``card``.
    """
    import lightning.pytorch as pl

    from workbench.learn.callbacks import BestWeights, EpochLog
    from workbench.learn.datamodule import WindowDataModule
    from workbench.learn.legmodel import LearnedLegModel
    from workbench.learn.module import WrenchRegressor
    from workbench.learn.nets import build_net
    from workbench.tracking import log_metrics, run_tags

    cfg = cfg.validate()
    _quiet_lightning()
    hybrid = cfg.model.variant == "ef_residual"
    t_start = time.perf_counter()
    prepared = _prepared_data(cfg, prepared, hybrid)
    threads = apply_torch_threads(cfg.trainer.torch_threads)
    pl.seed_everything(cfg.trainer.seed, workers=False, verbose=False)
    dm = WindowDataModule(prepared, cfg.data, with_base=hybrid, seed=cfg.trainer.seed)
    net = build_net(cfg.model, cfg.data.seq_len)
    module = WrenchRegressor(net, cfg.optim)
    campaigns = prepared.table.campaigns()
    tags = run_tags(kind=kind, campaigns=campaigns, variant=cfg.model.variant, dvc_stage=cfg.tracking.dvc_stage,
                    **(extra_tags or {}))
    metrics: dict = {}
    objects: dict = {"prepared": prepared, "datamodule": dm, "module": module}
    with _mlflow_run(cfg, tags, default_run_name(cfg, campaigns, kind, extra_tags), parent_run_id) as run:
        if run is not None:
            objects["run_id"] = run.info.run_id
            _log_inputs(cfg, dm, prepared, threads)
        log = EpochLog(cfg.trainer.max_epochs, report, mlflow_run=run is not None)
        best = BestWeights()
        trainer = _trainer(cfg, [log, best, *callbacks])
        t_fit = time.perf_counter()
        _fit(trainer, module, dm)
        fit_s = time.perf_counter() - t_fit
        best.restore(module)
        stop = stop_reason(trainer, cfg, len(log.history))
        if run is not None:
            import mlflow

            mlflow.set_tags({"stop_reason": stop["reason"], "stop_detail": stop["detail"]})
        info = {"campaigns": campaigns, "git_commit": tags["git_commit"], "best_epoch": best.best_epoch,
                "trained_windows_per_epoch": dm.windows_per_epoch(), **({"run_id": run.info.run_id} if run else {})}
        model = LearnedLegModel(net, model=cfg.model, seq_len=cfg.data.seq_len, dt_s=prepared.dt_s, norm=prepared.norm,
                                info=info)
        metrics.update(_fit_metrics(stop, best, log.history, fit_s, t_start))
        if score_test:
            metrics.update(_test_metrics(cfg, prepared, model))
        summary = _summary(metrics)
        card = model_card(cfg, model, prepared, summary, log.history, curve=bool(cfg.model_dir))
        objects.update(model=model, history=log.history, card=card)
        if run is not None:
            log_metrics(summary, sep="_")
            if log_model:
                objects.update(_log_model(cfg, run, card, prepared, tags))
    metrics["summary"] = summary
    return metrics, objects


def _prepared_data(cfg: LearnSettings, prepared, hybrid: bool):
    """The data to train on: ``cfg.data.paths`` read and prepared, or ``prepared`` (given the EF base a hybrid needs)."""
    from workbench.learn.datamodule import prepare_data
    from workbench.learn.windows import read_table

    if prepared is None:
        return prepare_data(read_table(cfg.data.paths), cfg.data, need_ef=hybrid)
    if hybrid and prepared.base is None:
        return prepare_data(prepared.table, cfg.data, need_ef=True, split=prepared.split)
    return prepared


def _log_inputs(cfg: LearnSettings, dm, prepared, threads) -> None:
    """Log the configuration, the window and set counts and the split (``split.json``) to the active MLflow run."""
    import mlflow

    from workbench.tracking import log_params

    log_params({**cfg.to_dict(), "n_train_windows": len(dm.ends["train"]),
                "n_val_windows": len(dm.ends["val"]), "n_test_windows": len(dm.ends["test"]),
                "windows_per_epoch": dm.windows_per_epoch(), "torch_threads_used": threads or "default",
                **{f"n_{k}_sets": v for k, v in prepared.split.counts().items()}})
    mlflow.log_dict(prepared.split.to_dict(prepared.table), "split.json")


def _trainer(cfg: LearnSettings, cbs: list):
    """The Lightning trainer on the CPU, with ``cbs`` (and early stopping when the configuration asks for it)."""
    import lightning.pytorch as pl
    from lightning.pytorch.callbacks import EarlyStopping

    if cfg.trainer.early_stop_patience:
        cbs.append(EarlyStopping("val_loss", patience=cfg.trainer.early_stop_patience, mode="min"))
    return pl.Trainer(
        accelerator="cpu", devices=1, max_epochs=cfg.trainer.max_epochs, logger=False,
        enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
        num_sanity_val_steps=0, gradient_clip_val=cfg.optim.grad_clip or None, callbacks=cbs,
        max_time=timedelta(seconds=cfg.trainer.max_time_s) if cfg.trainer.max_time_s else None,
    )


def _fit(trainer, module, dm) -> None:
    """``trainer.fit``, with an interruption raised as KeyboardInterrupt."""
    try:
        trainer.fit(module, datamodule=dm)
    except SystemExit:
        # Lightning turns Ctrl-C (and SIGTERM under workbench.procs) into sys.exit(1) after its
        # own shutdown: give callers their KeyboardInterrupt back (Optuna fails the trial, the
        # MLflow run ends KILLED, the CLI says "interrupted")
        if trainer.interrupted:
            raise KeyboardInterrupt("training interrupted") from None
        raise


def _fit_metrics(stop: dict, best, history: list[dict], fit_s: float, t_start: float) -> dict:
    """Why and when training stopped, the best validation loss, timings and the median training throughput."""
    wps = [h["windows_per_s"] for h in history if h["windows_per_s"] == h["windows_per_s"]]
    return {"stop_reason": stop["reason"], "stop_detail": stop["detail"],
            "best_val_loss": best.best, "best_epoch": best.best_epoch, "epochs": len(history),
            "fit_s": fit_s, "total_s": time.perf_counter() - t_start,
            "train_windows_per_s": sorted(wps)[len(wps) // 2] if wps else float("nan")}


def _test_metrics(cfg: LearnSettings, prepared, model) -> dict:
    """The model and the EF scored on the held-out test runs (none: no metrics)."""
    from workbench.hydro.ef import EmpiricalFormula
    from workbench.learn.metrics import score_runs

    test_runs = prepared.runs("test")
    if not len(test_runs):
        return {}
    scored = score_runs(prepared.table, test_runs, {"lstm": model, "ef": EmpiricalFormula()},
                        skip=cfg.data.seq_len - 1)
    return {"test": scored, "test_mse": scored["lstm"]["mse"], "test_r2": scored["lstm"]["r2"],
            "test_nmse": sum(1 - v for v in scored["lstm"]["r2"].values()) / 6}


def stop_reason(trainer, cfg: LearnSettings, epochs: int) -> dict:
    """Why training stopped: ``max_epochs``, ``early_stopping`` (patience) or ``time_cap`` (``max_time_s``).

    Returns ``{"reason", "detail"}``; the detail is the sentence shown and recorded, e.g.
    ``time cap max_time_s=30 reached after epoch 2 of max_epochs=4``.
    """
    from lightning.pytorch.callbacks import EarlyStopping, Timer

    max_epochs = cfg.trainer.max_epochs
    for cb in trainer.callbacks:
        if isinstance(cb, EarlyStopping) and cb.stopped_epoch > 0:
            return {"reason": "early_stopping",
                    "detail": f"early stopping: val_loss did not improve for {cb.patience} epoch(s) "
                              f"(patience), after epoch {epochs} of max_epochs={max_epochs}"}
    for cb in trainer.callbacks:
        if isinstance(cb, Timer) and cb._duration is not None and cb.time_elapsed() >= cb._duration:
            if epochs < max_epochs:
                return {"reason": "time_cap",
                        "detail": f"time cap max_time_s={cfg.trainer.max_time_s:g} reached after epoch {epochs} "
                                  f"of max_epochs={max_epochs}"}
    if epochs >= max_epochs:
        return {"reason": "max_epochs", "detail": f"max_epochs={max_epochs} reached"}
    return {"reason": "other", "detail": f"stopped after epoch {epochs} of max_epochs={max_epochs} "
                                         "(a callback asked to stop)"}


def _log_model(cfg: LearnSettings, run, card: dict[str, bytes], prepared, tags: dict) -> dict:
    """Log the model card as an MLflow pyfunc model of the run; register it when the configuration says so.

    The card is laid out in a temporary folder for MLflow (:func:`workbench.learn.legmodel.staged_folder`);
    its learning curve, when it has one, is also logged as an artifact of the run.
    Returns ``{"model_id"}`` (the MLflow logged model) and, when registered, ``{"model_version"}``.
    """
    import mlflow

    from workbench.learn.legmodel import staged_folder
    from workbench.learn.pyfunc import log_leg_model
    from workbench.tracking import MODEL_ARTIFACT, MODEL_ID_TAG, register_model

    keep = ("campaign", "variant", "git_commit", "dvc_stage")
    with staged_folder(card) as folder:
        info = log_leg_model(folder, table=prepared.table, name=MODEL_ARTIFACT,
                             tags={k: tags[k] for k in keep if k in tags})
        if "learning_curve.png" in card:
            mlflow.log_artifact(str(folder / "learning_curve.png"))
    mlflow.set_tag(MODEL_ID_TAG, info.model_id)
    out = {"model_id": info.model_id}
    if cfg.tracking.register:
        out["model_version"] = register_model(mlflow.get_run(run.info.run_id), cfg.tracking.registered_model,
                                              cfg.tracking.alias, tags={k: tags[k] for k in keep if k in tags})
    return out


def _summary(metrics: dict) -> dict:
    """The flat, JSON-friendly summary: what metrics.json holds and MLflow logs."""
    out = {k: metrics[k] for k in ("stop_reason", "stop_detail", "best_val_loss", "best_epoch", "epochs", "fit_s",
                                   "train_windows_per_s")}
    if "test" in metrics:
        lstm, ef = metrics["test"]["lstm"], metrics["test"]["ef"]
        out["test_nmse"] = metrics["test_nmse"]
        for c in _LOG_CHANNELS:
            out[f"test_mse_{c}"] = lstm["mse"][c]
            out[f"test_r2_{c}"] = lstm["r2"][c]
            out[f"test_ef_mse_{c}"] = ef["mse"][c]
            out[f"test_mse_ratio_{c}"] = lstm["mse"][c] / ef["mse"][c] if ef["mse"][c] > 0 else float("nan")
    return out


def _history_csv(history: list[dict]) -> str:
    buf = io.StringIO()
    if history:
        w = csv.DictWriter(buf, fieldnames=list(history[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(history)
    return buf.getvalue()


def _json_bytes(doc) -> bytes:
    return (json.dumps(doc, indent=2) + "\n").encode("utf-8")


def model_card(cfg: LearnSettings, model, prepared, summary: dict, history: list[dict], *,
               curve: bool = True) -> dict[str, bytes]:
    """The model folder's files as bytes: name -> content.

    The model (``model.json``, ``weights.pt``), ``config.json``, ``split.json``, ``metrics.json``,
    ``history.csv`` and, with ``curve`` and a history, ``learning_curve.png``. The caller writes
    them (``workbench train``: atomically, as one set).
    """
    from workbench.learn.legmodel import model_files

    card = model_files(model)
    card["config.json"] = _json_bytes(cfg.to_dict())
    card["split.json"] = _json_bytes(prepared.split.to_dict(prepared.table))
    card["metrics.json"] = _json_bytes(summary)
    card["history.csv"] = _history_csv(history).encode("utf-8")
    if curve and history:
        from workbench.learn.figures import learning_curve

        buf = io.BytesIO()
        learning_curve(history).savefig(buf, dpi=100, format="png")  # a matplotlib Figure: no pyplot state
        card["learning_curve.png"] = buf.getvalue()
    return card
