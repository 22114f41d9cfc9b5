"""Hyper-parameter search: an Optuna study over sequence length, size, dropout, learning rate, batch and variant.

The search in three modules, one concern each:

- here, the study: its settings (``tune`` section), the search space, the objective (one
  ``train(cfg)`` per trial), :func:`run_worker` (one worker's share of trials), :func:`run_study`
  (create or resume the study, parent MLflow run, register the best; returns the summary);
- :mod:`workbench.learn.tune_summary`: what a study reports (progress lines, the summary of a
  command's trials, ``best.json`` and ``trials.csv`` as bytes: :func:`~workbench.learn.tune_summary.tune_files`);
- :mod:`workbench.learn.tune_storage`: where the study lives (an Optuna journal file
  ``.optuna/<study>.journal`` at the project root by default, fast and safe for processes on one
  machine, or any Optuna storage URL such as ``postgresql://...`` for a cluster), its lock,
  heartbeats, the retry of dead workers' trials, per-trial sampler seeds;
- :mod:`workbench.learn.tune_workers`: the worker processes (``python -m
  workbench.learn.tune_workers --worker -``), each taking an exact share of ``n_trials`` so that
  no trial is lost or run twice; running the same command on another machine against the same
  storage adds its trials to the same study.

Several commands may share one study at once (on one machine or many): each command has an id
(``command`` user attribute of its trials), counts and reports only its own trials ("trial 3/4"),
and every trial draws its sampler seed from its own trial number (:mod:`workbench.learn.tune_storage`),
so no two workers of any command repeat each other's draws. Workers record heartbeats; a trial
whose worker died (SIGKILL, a lost machine) is failed and retried once, the retry run by the
command that lost the trial while it runs, and the command restarts a worker that was killed for
the trials it still owed. Workers die with the command (SIGINT,
SIGTERM, even its SIGKILL: :mod:`workbench.procs`), and their specification travels on stdin, so
nothing is left in the temp folder. Each trial is one
``train(cfg)`` call with fewer epochs and windows and no test scoring, a child MLflow run (pruned
trials end KILLED, tagged ``state=pruned``), pruned on the validation loss by Optuna's median rule after
``n_warmup_steps`` epochs. The best
trial (lowest validation loss, never the test score) has its logged model registered under
the ``tuned`` alias; its parameters go to ``best.json`` as ``--set`` overrides for ``workbench train``.
Nothing here writes a file: ``workbench tune --out`` writes ``tune_files(summary)`` through ``workbench/atomic.py``.
"""

from __future__ import annotations

import json
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

from workbench.errors import ContractError, StageError
from workbench.learn.config import LearnSettings, config_from_dict
from workbench.learn.tune_summary import progress_callback, summarise
from workbench.threads import AUTO, idle_cores

#: short search-parameter names -> configuration keys (any dotted key may be used directly too)
PARAM_KEYS = {"seq_len": "data.seq_len", "hidden_size": "model.hidden_size", "num_layers": "model.num_layers",
              "dropout": "model.dropout", "lr": "optim.lr", "batch_size": "data.batch_size",
              "variant": "model.variant", "backbone": "model.backbone"}


@dataclass(frozen=True)
class TuneSettings:
    """The ``tune`` section of ``pipelines/learn.yaml``."""

    study: str = "fed-lstm"
    storage: str | None = None
    n_trials: int = 8
    workers: int = 1
    max_epochs: int = 4
    train_windows_per_epoch: int | None = 20000
    sampler_seed: int = 0
    pruner: Mapping[str, Any] = field(default_factory=lambda: {"n_startup_trials": 2, "n_warmup_steps": 1})
    space: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    register_best: bool = True
    alias: str = "tuned"
    #: MLflow experiment of the study's runs (None: the train section's tracking.experiment)
    experiment: str | None = None
    #: seconds between a worker's heartbeats for its running trial
    heartbeat_interval_s: int = 10
    #: a RUNNING trial without a heartbeat for this long is failed (and retried); a dead worker on
    #: this machine is noticed at once
    grace_period_s: int = 120
    #: retries of a trial whose worker died
    max_retry: int = 1

    @classmethod
    def from_dict(cls, d: Mapping[str, Any] | None, *, path: str | Path | None = None) -> "TuneSettings":
        """From the YAML's ``tune`` section (workbench.params: unknown keys, wrong types are a ParamsError)."""
        from workbench.params import build

        return build(cls, d, key="tune", path=path)


#: the name before issue 17 (settings classes end in ``Settings``); kept for existing imports
TuneCfg = TuneSettings


def suggest(trial, space: Mapping[str, Mapping[str, Any]]) -> dict[str, Any]:
    """Sample the search space: ``{name: {type: int|float|categorical, low, high, step, log, choices}}``."""
    out = {}
    for name, spec in space.items():
        kind = spec.get("type", "float")
        if kind == "categorical":
            out[name] = trial.suggest_categorical(name, list(spec["choices"]))
        elif kind == "int":
            out[name] = trial.suggest_int(name, int(spec["low"]), int(spec["high"]), step=int(spec.get("step", 1)),
                                          log=bool(spec.get("log", False)))
        elif kind == "float":
            out[name] = trial.suggest_float(name, float(spec["low"]), float(spec["high"]), log=bool(spec.get("log", False)),
                                            step=spec.get("step"))
        else:
            raise ContractError(f"tune.space.{name}: unknown type {kind!r}", hint="int, float or categorical")
    return out


def trial_config(base: LearnSettings, tune: TuneSettings, params: Mapping[str, Any], study: str,
                 number: int) -> LearnSettings:
    """The training configuration of one trial: base + sampled parameters + the search's short budget."""
    over: dict[str, Any] = {PARAM_KEYS.get(k, k): v for k, v in params.items()}
    over.update({"trainer.max_epochs": tune.max_epochs, "data.train_windows_per_epoch": tune.train_windows_per_epoch,
                 "model_dir": None, "tracking.register": False,
                 "tracking.run_name": None})  # named by train(): "trial 003 <study> <campaigns> @<commit>"
    return base.with_overrides(over)


_CACHE: dict[str, Any] = {}


def _prepared(base: LearnSettings, need_ef: bool):
    """Read and prepare the data once per process (trials only differ in how they window it)."""
    from workbench.learn.datamodule import prepare_data
    from workbench.learn.windows import read_table

    key = json.dumps([base.data.paths, base.to_dict()["data"]["split"], need_ef])
    if key not in _CACHE:
        _CACHE.clear()
        _CACHE[key] = prepare_data(read_table(base.data.paths), base.data, need_ef=need_ef)
    return _CACHE[key]


def make_objective(base: LearnSettings, tune: TuneSettings, study_name: str, parent_run_id: str | None, worker: int = 0,
                   command: str | None = None):
    """The Optuna objective: train one trial configuration, return its best validation loss."""
    from optuna_integration import PyTorchLightningPruningCallback

    from workbench.learn.train import train

    variants = tune.space.get("variant", {}).get("choices", [base.model.variant])
    need_ef = "ef_residual" in variants or base.model.variant == "ef_residual"

    from workbench.learn.tune_storage import trial_seed

    def objective(trial) -> float:
        # who runs this trial: progress and summaries count a command's own trials only
        trial.set_user_attr("command", command)
        trial.set_user_attr("worker", worker)
        trial.set_user_attr("sampler_seed", trial_seed(tune.sampler_seed, trial.number))
        params = suggest(trial, tune.space)
        cfg = trial_config(base, tune, params, study_name, trial.number)
        metrics, objects = train(cfg, prepared=_prepared(base, need_ef),
                                 callbacks=[PyTorchLightningPruningCallback(trial, monitor="val_loss")],
                                 parent_run_id=parent_run_id, kind="trial", score_test=False,
                                 extra_tags={"study": study_name, "trial": trial.number, "worker": worker})
        if "run_id" in objects:
            trial.set_user_attr("mlflow_run_id", objects["run_id"])
        trial.set_user_attr("epochs", metrics["epochs"])
        return float(metrics["best_val_loss"])

    return objective


def make_pruner(spec: Mapping[str, Any]):
    """``{type: median (default), n_startup_trials, n_warmup_steps}``, ``{type: threshold, upper}`` or ``{type: none}``."""
    import optuna

    spec = dict(spec)
    kind = spec.pop("type", "median")
    if kind == "median":
        return optuna.pruners.MedianPruner(**spec)
    if kind == "threshold":
        return optuna.pruners.ThresholdPruner(**spec)
    if kind == "none":
        return optuna.pruners.NopPruner()
    raise ContractError(f"tune.pruner.type {kind!r} unknown", hint="median, threshold or none")


def run_worker(spec: Mapping[str, Any], report: Callable[[str], None] | None = None) -> None:
    """One worker: load the shared study and run its share of trials (also used in-process for 1 worker)."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    base = config_from_dict(spec["config"])
    tune = TuneSettings.from_dict(spec["tune"])
    from workbench.learn.tune_storage import TrialSeededTPE, resolve_storage

    storage, _ = resolve_storage(spec["storage"], spec["study"], tune)
    storage.command = spec.get("command_record")  # whose worker this is: owner records, retries (tune_storage)
    # seeded per trial number: distinct across workers and commands; the constant liar keeps
    # concurrent workers from proposing the same point while a trial runs
    sampler = TrialSeededTPE(tune.sampler_seed, constant_liar=True)
    pruner = make_pruner(tune.pruner)
    study = optuna.load_study(study_name=spec["study"], storage=storage, sampler=sampler, pruner=pruner)
    if spec.get("tracking_uri"):  # the store the command resolved (its runs' parent is there), not os.environ
        base = base.with_overrides({"tracking.tracking_uri": spec["tracking_uri"]})
    objective = make_objective(base, tune, spec["study"], spec.get("parent_run_id"), int(spec["worker"]),
                               spec.get("command"))
    tag = f" [worker {spec['worker']}]" if spec.get("n_workers", 1) > 1 else ""
    cbs = [progress_callback(spec["total"], set(spec["baseline"]), report, tag, spec.get("command"))] if report else []
    study.optimize(objective, n_trials=int(spec["n_trials"]), catch=(Exception,), callbacks=cbs,
                   gc_after_trial=False)


def run_study(base: LearnSettings, tune: TuneSettings, *, fresh: bool = False,
              report: Callable[[str], None] | None = None) -> dict:
    """Create/resume the study, run its trials in ``tune.workers`` processes, register the best; returns a summary.

    The summary (:func:`~workbench.learn.tune_summary.summarise`) is what ``best.json`` and
    ``trials.csv`` are made of (:func:`~workbench.learn.tune_summary.tune_files`); nothing is written here.
    """
    import mlflow
    import optuna

    from workbench import procs
    from workbench.learn.tune_storage import command_ended, command_record, fail_stale

    procs.install()  # SIGTERM/SIGHUP clean up as Ctrl-C does: workers stopped, trials failed, runs ended
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    base = _share_threads(base, tune)
    study, storage, where = _open_study(tune, fresh)
    baseline = [t.number for t in study.get_trials(deepcopy=False)]
    command = uuid.uuid4().hex[:12]
    # this process is the command: it fails and queues again its own killed workers' trials (tune_storage)
    storage.command = record = command_record(command)
    fail_stale(study)  # trials of workers that died earlier: failed (and queued again) now
    if report:
        report(f"study {tune.study!r} in {where}: {len(baseline)} earlier trial(s); running {tune.n_trials} "
               f"in {tune.workers} worker process(es)")
    parent_id, tracking_uri = _start_parent_run(base, tune, where)
    status = "FAILED"
    try:
        spec = {"config": base.to_dict(), "tune": _tune_dict(tune), "storage": where, "study": tune.study,
                "parent_run_id": parent_id, "tracking_uri": tracking_uri, "total": tune.n_trials,
                "baseline": baseline, "n_workers": tune.workers, "command": command,
                "command_record": record}
        elapsed = _run_trials(spec, tune, report, study)
        fail_stale(study)
        summary = summarise(optuna.load_study(study_name=tune.study, storage=storage), set(baseline), elapsed,
                            command=command)
        summary["storage"] = where
        if summary["best"] is None:
            raise StageError(f"study {tune.study!r}: no trial completed; first failure: {summary['first_failure']}")
        _record_best(base, tune, summary, elapsed, storage)
        status = "FINISHED"
        return summary
    except KeyboardInterrupt:
        status = "KILLED"
        raise
    finally:
        command_ended(record)
        if parent_id is not None:
            mlflow.set_tag("state", {"FINISHED": "complete", "KILLED": "interrupted"}.get(status, "failed"))
            mlflow.end_run(status=status)


def _share_threads(base: LearnSettings, tune: TuneSettings) -> LearnSettings:
    """With several workers and automatic torch threads, the idle cores shared out among the workers."""
    if tune.workers > 1 and base.trainer.torch_threads == AUTO:
        # the idle cores are shared out among the worker processes, not claimed by each of them
        return base.with_overrides({"trainer.torch_threads": max(1, idle_cores() // tune.workers)})
    return base


def _open_study(tune: TuneSettings, fresh: bool):
    """The study (deleted first when ``fresh``), created or loaded; returns ``(study, storage, where)``."""
    import optuna

    from workbench.learn.tune_storage import resolve_storage

    storage, where = resolve_storage(tune.storage, tune.study, tune)
    if fresh and tune.study in optuna.get_all_study_names(storage):
        optuna.delete_study(study_name=tune.study, storage=storage)
    study = optuna.create_study(study_name=tune.study, storage=storage, direction="minimize", load_if_exists=True)
    return study, storage, where


def _start_parent_run(base: LearnSettings, tune: TuneSettings, where: str) -> tuple[str | None, str | None]:
    """The study's parent MLflow run, started with the settings logged; ``(run id, tracking URI)``, Nones untracked."""
    if not base.tracking.enabled:
        return None, None
    import mlflow

    from workbench.tracking import log_params, run_name, run_tags, setup

    tracking_uri = setup(base.tracking.tracking_uri, base.tracking.experiment)
    campaigns = _campaigns(base)
    parent = mlflow.start_run(run_name=run_name("tune", tune.study, campaigns, base.tracking.dvc_stage), tags=run_tags(
        kind="tune", campaigns=campaigns, dvc_stage=base.tracking.dvc_stage, study=tune.study, storage=where))
    log_params({"tune": {k: v for k, v in _tune_dict(tune).items() if k != "space"}, "space": _tune_dict(tune)["space"],
                "train": base.to_dict()})
    return parent.info.run_id, tracking_uri


def _run_trials(spec: dict, tune: TuneSettings, report: Callable[[str], None] | None, study) -> float:
    """This command's trials, in this process (one worker) or in worker processes; returns the seconds taken."""
    from workbench.learn.tune_workers import spawn_workers

    t0 = time.perf_counter()
    if tune.workers <= 1:
        run_worker({**spec, "worker": 0, "n_trials": tune.n_trials}, report)
    else:
        spawn_workers(spec, tune.n_trials, tune.workers, report, study)
    return time.perf_counter() - t0


def _record_best(base: LearnSettings, tune: TuneSettings, summary: dict, elapsed: float, storage) -> None:
    """When tracked: register the best trial's model (if asked) and log the study's metrics and summary."""
    if not base.tracking.enabled:
        return
    import mlflow

    from workbench.tracking import log_metrics

    if tune.register_best and summary["best"].get("mlflow_run_id"):
        summary["best"]["model_version"] = _register_best(base, tune, summary["best"], storage)
    log_metrics({"best_val_loss": summary["best"]["value"], "n_complete": summary["counts"]["COMPLETE"],
                 "n_pruned": summary["counts"]["PRUNED"], "n_failed": summary["counts"]["FAIL"],
                 "elapsed_s": elapsed})
    mlflow.log_dict(summary, "tune_summary.json")


def _campaigns(base: LearnSettings) -> list[str]:
    import polars as pl

    from workbench.learn.windows import expand_paths

    ids: list[str] = []
    for p in expand_paths(base.data.paths):
        try:
            ids += pl.scan_parquet(p).select(pl.col("campaign_id").unique()).collect()["campaign_id"].to_list()
        except Exception:  # noqa: BLE001 - the workers report a bad file properly
            pass
    return sorted(set(ids))


def _tune_dict(tune: TuneSettings) -> dict:
    return {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in tune.__dict__.items()}


def _register_best(base: LearnSettings, tune: TuneSettings, best: dict, storage) -> str:
    """Register the best trial's model under ``tune.alias``, unless the alias already names a better trial.

    Workers on several machines each register at their end; one that read the study just before
    another's last trial completed must not move the alias back to a worse trial of the study.
    """
    import optuna
    from mlflow import MlflowClient

    from workbench.tracking import register_model

    client = MlflowClient()
    name = base.tracking.registered_model
    values = {t.user_attrs.get("mlflow_run_id"): t.value
              for t in optuna.load_study(study_name=tune.study, storage=storage).get_trials(
                  deepcopy=False, states=(optuna.trial.TrialState.COMPLETE,))}
    try:
        current = client.get_model_version_by_alias(name, tune.alias)
    except Exception:  # noqa: BLE001 - no such alias (or model) yet
        current = None
    if current is not None and current.run_id in values and values[current.run_id] <= best["value"]:
        return str(current.version)
    run = client.get_run(best["mlflow_run_id"])
    return register_model(run, name, tune.alias,
                          tags={"study": tune.study, "trial": str(best["number"]), **{
                              k: run.data.tags.get(k, "") for k in ("campaign", "variant", "git_commit", "dvc_stage")}})
