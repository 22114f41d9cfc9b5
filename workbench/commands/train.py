"""``workbench train``: train one leg force model configuration (FED-LSTM by default)."""

from __future__ import annotations

from workbench.commands._help import add_verb

EXAMPLES = """\
  # the paper's FED-LSTM on the interpolated demo campaign (writes scratch/models/fed-lstm and logs
  # the run and the model to MLflow; registers nothing)
  workbench train --data datasets/processed/interp/demo-tunnel.parquet

  # register it too and point an alias at it; then any MLflow client can load it:
  #   mlflow.pyfunc.load_model("models:/fed-lstm@candidate").predict(frame)
  workbench train --data d.parquet --out scratch/models/candidate --register --alias candidate

  # a GRU variant, two campaigns, not promoted to champion
  workbench train --data a.parquet b.parquet --set model.variant=gru --alias candidate

  # the EF-residual hybrid, quick look without MLflow
  workbench train --data d.parquet --set model.variant=ef_residual --set trainer.max_epochs=3 --no-mlflow --out /tmp/m

  # the paper's 16-tick windows as their own registered model (models:/fed-lstm-16@champion), the
  # 32-tick champion untouched
  workbench train --data datasets/processed/interp --set data.seq_len=16 \\
      --out datasets/models/fed-lstm-16 --registered-model fed-lstm-16

  # adopt the best parameters of a search (tune writes them to best.json as overrides)
  workbench train --data d.parquet --set data.seq_len=24 --set model.hidden_size=96

  # record on a shared MLflow server
  workbench train --data d.parquet --tracking-uri http://mlflow.lab:5000
"""


def register(sub) -> None:
    """Add the ``train`` verb."""
    from workbench.learn.config import add_common_options

    p = add_verb(sub, "train", help="train a leg force model (FED-LSTM, GRU, MLP, EF-residual hybrid)",
                 description="Train one configuration of pipelines/learn.yaml (section train) on processed tunnel "
                             "data: windows of train.data.seq_len ticks (32) of (V_flow, theta_H, theta_K, omega_H, omega_K) -> six-channel "
                             "wrench, split 7:1:2 by motion-parameter set. Prints one line per epoch, scores the "
                             "model and the EF on the held-out test sets, writes the model folder, records the run "
                             "in MLflow and registers the model with an alias.",
                 examples=EXAMPLES)
    add_common_options(p)
    p.add_argument("--out", metavar="DIR", help="model folder to write (default: the file's model_dir, "
                                                "scratch/models/fed-lstm: never the pipeline's datasets/models)")
    p.add_argument("--registered-model", metavar="NAME",
                   help="registered model to add the new version to (default: the file's tracking.registered_model, "
                        "fed-lstm); e.g. fed-lstm-16 for the paper's 16-tick windows, so its champion is its own")
    p.add_argument("--alias", help="registry alias to point at the new version (default: the file's, champion)")
    reg = p.add_mutually_exclusive_group()
    reg.add_argument("--register", action="store_true",
                     help="register the model and point the alias at it (the pipeline's train stages do; an ad-hoc "
                          "run does not, unless asked: it never moves fed-lstm@champion by accident)")
    reg.add_argument("--no-register", action="store_true", help="log the model but do not register it (the default)")
    p.add_argument("--run-name", help="MLflow run name")
    p.add_argument("--quiet", action="store_true", help="no per-epoch lines")
    p.set_defaults(func=run)


def run(args) -> int:
    """Train and report."""
    from workbench.console import info
    from workbench.learn.config import cli_config

    cfg = cli_config(args)
    over = _overrides(args)
    cfg = cfg.with_overrides(over) if over else cfg
    info(f"train: {cfg.model.variant} {cfg.model.hidden_size}x{cfg.model.num_layers}, seq_len {cfg.data.seq_len}, "
         f"data {', '.join(cfg.data.paths)}")
    from workbench.learn.train import train
    if cfg.model_dir:
        from workbench.atomic import check_replaceable

        check_replaceable(cfg.model_dir, "train")  # a wrong --out is refused before the training, not after

    metrics, objects = train(cfg, report=None if args.quiet else info)
    if cfg.model_dir:
        write_model_card(cfg.model_dir, objects["card"])
    _report_training(metrics)
    _report_records(cfg, objects)
    return 0


def _overrides(args) -> dict:
    """The settings the command line overrides, as dotted keys of the train section."""
    over = {}
    if args.out:
        over["model_dir"] = args.out
    if args.alias:
        over["tracking.alias"] = args.alias
    if args.registered_model:
        over["tracking.registered_model"] = args.registered_model
    if args.no_register:
        over["tracking.register"] = False
    if args.register:
        over["tracking.register"] = True
    if args.run_name:
        over["tracking.run_name"] = args.run_name
    return over


def _report_training(metrics) -> None:
    """Print why training stopped, the best epoch, the speed and the held-out test scores."""
    import torch

    from workbench.console import info

    s = metrics["summary"]
    info(f"stopped: {s['stop_detail']}")
    info(f"best epoch {s['best_epoch']}/{s['epochs']}: val loss {s['best_val_loss']:.4f}; "
         f"{s['train_windows_per_s']:,.0f} training windows/s on {torch.get_num_threads()} torch thread(s)")
    if "test" in metrics:
        ratios = "  ".join(f"{c} {s[f'test_mse_ratio_{c}']:.2f}" for c in ("fy_n", "fz_n", "tx_nm"))
        info(f"held-out test sets: MSE LSTM/EF {ratios}; R^2 " +
             "  ".join(f"{c} {metrics['test_r2'][c]:.2f}" for c in ("fy_n", "fz_n", "tx_nm")))


def _report_records(cfg, objects) -> None:
    """Print where the model went: its folder, its MLflow run and model, its registered version."""
    from workbench.console import info

    if cfg.model_dir:
        info(f"model folder: {cfg.model_dir}")
    if "run_id" in objects:
        import mlflow

        info(f"MLflow run '{mlflow.get_run(objects['run_id']).info.run_name}' ({objects['run_id']}), "
             f"model {objects.get('model_id', 'not logged')}")
    if "model_version" in objects:
        uri = f"models:/{cfg.tracking.registered_model}@{cfg.tracking.alias}"
        info(f"registered {cfg.tracking.registered_model} version {objects['model_version']} "
             f"as @{cfg.tracking.alias} (run {objects['run_id']}); mlflow.pyfunc.load_model({uri!r}) loads it")


def write_model_card(target, card: dict[str, bytes]):
    """Write a model card (:func:`workbench.learn.train.model_card`: name -> bytes) as the folder ``target``.

    One set: built beside ``target`` and swapped in whole (:func:`workbench.atomic.atomic_dir`), so a
    kill leaves the previous folder or the new one; a folder ``train`` did not write is refused.
    """
    from pathlib import Path

    from workbench.atomic import atomic_dir

    with atomic_dir(target, verb="train") as tmp:
        for name, data in card.items():
            (Path(tmp) / name).write_bytes(data)
    return Path(target)
