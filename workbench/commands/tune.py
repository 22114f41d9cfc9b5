"""``workbench tune``: an Optuna search over the leg model's hyper-parameters, shared across processes."""

from __future__ import annotations

from workbench.commands._help import add_verb

EXAMPLES = """\
  # the demo-sized search of pipelines/learn.yaml (4 trials, 2 worker processes, pruning)
  workbench tune --data datasets/processed/interp/demo-tunnel.parquet

  # a longer search; run the same command again later (or on a second shell) to add trials
  workbench tune --data d.parquet --study big --n-trials 40 --workers 2 --set trainer.max_epochs=8

  # a cluster: every machine runs this against one PostgreSQL study and one MLflow server
  workbench tune --data d.parquet --study big --n-trials 20 \\
      --storage postgresql://optuna@db.lab/optuna --tracking-uri http://mlflow.lab:5000

  # start the study afresh (deletes its earlier trials), as the DVC stage does
  workbench tune --data d.parquet --fresh --out datasets/models/tune
"""


def register(sub) -> None:
    """Add the ``tune`` verb."""
    from workbench.learn.config import add_common_options

    p = add_verb(sub, "tune", help="hyper-parameter search (Optuna, pruning, several worker processes)",
                 description="Search sequence length, hidden size, layers, dropout, learning rate, batch size and "
                             "variant (pipelines/learn.yaml, section tune) with Optuna's TPE sampler and median "
                             "pruning on the validation loss. The study is stored in .optuna/<study>.journal (or "
                             "--storage) so it survives a restart and several processes share it. Each trial is a "
                             "child MLflow run of the search's run; the best trial's model is registered with the "
                             "alias 'tuned'. Prints one line per finished trial with the best so far.",
                 examples=EXAMPLES)
    add_common_options(p)
    p.add_argument("--study", help="study name (default: the file's tune.study)")
    p.add_argument("--storage", help="Optuna storage: a .journal file or a URL such as postgresql://... "
                                     "(default: .optuna/<study>.journal)")
    p.add_argument("--n-trials", type=int, help="trials this command adds (default: the file's tune.n_trials)")
    p.add_argument("--workers", type=int, help="worker processes (default: the file's tune.workers)")
    p.add_argument("--fresh", action="store_true", help="delete the study's earlier trials first")
    p.add_argument("--out", metavar="DIR", help="write best.json and trials.csv here")
    p.set_defaults(func=run)


def run(args) -> int:
    """Run the search and report the best trial."""
    import dataclasses

    from workbench.console import info
    from workbench.errors import ContractError
    from workbench.learn.config import cli_config
    from workbench.learn.tune import TuneSettings, run_study
    from workbench.params import load_settings

    cfg = cli_config(args)
    tune = load_settings(TuneSettings, args.config, "tune")
    if tune.experiment and not args.experiment:  # the tune section's experiment, unless --experiment
        cfg = cfg.with_overrides({"tracking.experiment": tune.experiment})
    over = {k: v for k, v in {"study": args.study, "storage": args.storage, "n_trials": args.n_trials,
                              "workers": args.workers}.items() if v is not None}
    tune = dataclasses.replace(tune, **over)
    if tune.n_trials < 1 or tune.workers < 1:
        raise ContractError("--n-trials and --workers must be at least 1")
    if args.out:
        from workbench.atomic import check_replaceable

        check_replaceable(args.out, "tune")  # a wrong --out is refused before the study, not after
    summary = run_study(cfg, tune, fresh=args.fresh, report=info)
    if args.out:
        write_outputs(summary, args.out)
    c, b = summary["counts"], summary["best"]
    info(f"study {summary['study']!r}: {summary['n_trials_this_run']} trial(s) this run ({c['COMPLETE']} complete, "
         f"{c['PRUNED']} pruned, {c['FAIL']} failed), {summary['n_trials_total']} in the study, "
         f"{summary['elapsed_s']:.0f} s")
    info(f"best: trial {b['number']} val {b['value']:.4f}  overrides: {' '.join('--set ' + o for o in b['overrides'])}")
    if b.get("model_version"):
        info(f"registered {cfg.tracking.registered_model} version {b['model_version']} as @{tune.alias}")
    if args.out:
        info(f"wrote {args.out}/best.json and trials.csv")
    return 0


def write_outputs(summary: dict, out_dir):
    """``best.json`` and ``trials.csv`` (:func:`workbench.learn.tune_summary.tune_files`) in ``out_dir``, as one set.

    The folder is built beside ``out_dir`` and swapped in whole (:func:`workbench.atomic.atomic_dir`, the
    verb found from the call stack: ``tune``); a folder ``tune`` did not write is refused first.
    """
    from pathlib import Path

    from workbench.atomic import atomic_dir
    from workbench.learn.tune_summary import tune_files

    with atomic_dir(out_dir) as tmp:  # refuses a foreign folder before the summary is looked at
        for name, data in tune_files(summary).items():
            (Path(tmp) / name).write_bytes(data)
    return Path(out_dir)
