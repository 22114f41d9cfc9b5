"""``workbench virtual-lab pool``: the command line of the virtual pool (:func:`add_cli`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from workbench.errors import ParamsError, SettingError
from workbench.virtual_lab.pool_settings import PoolSettings

EXAMPLES = """\
  workbench virtual-lab pool datasets/raw/demo-pool --gaits datasets/gaits --params pipelines/trials.yaml
  workbench virtual-lab pool /tmp/pool --synthetic --fps 15 --size 640x360
  workbench virtual-lab pool /tmp/pool --gaits datasets/gaits --models ef lstm --best 8
  workbench virtual-lab pool /tmp/pool --gaits datasets/gaits --models ef lstm lstm16   # the 16-tick FED-LSTM too
  workbench score-trials /tmp/pool --out /tmp/pool-scores     # then compare with /tmp/pool/truth.json
"""


def add_cli(subparsers) -> None:
    """Add the ``pool`` subcommand to ``workbench virtual-lab``."""
    import argparse

    p = subparsers.add_parser(
        "pool", help="render an open-water trials folder (videos + trials.toml + truth.json)",
        description="Render overhead videos of the 4 m x 5 m tank from a tilted camera for the retained gaits "
        "of each model (simulated on the virtual lab's ground-truth physics) or for synthetic paths. "
        "Writes trials.toml per data contract section 2 and truth.json with the true scores.",
        epilog="examples:\n" + EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out", type=Path, help="trials folder to write (replaced atomically)")
    p.add_argument("--gaits", type=Path, default=None, help="folder of <task>-<model>.json gait files")
    p.add_argument("--synthetic", action="store_true", help="render built-in synthetic trajectories instead")
    p.add_argument("--params", type=Path, default=None, help="YAML with a 'pool' section (pipelines/trials.yaml)")
    p.add_argument("--models", nargs="+", default=None,
                   help="model names of the gait files <task>-<model>.json, any number (default: the file's pool.models, "
                        "else ef lstm); trials are labelled by pool.model_labels, else ef EF, lstm FED-LSTM, "
                        "lstm16 FED-LSTM-16 (lstmNN: FED-LSTM-NN)")
    p.add_argument("--best", type=int, default=None, help="render the best N retained gaits per model and task")
    p.add_argument("--fps", type=float, default=None, help="video frame rate")
    p.add_argument("--size", default=None, help="video size WxH, e.g. 960x540")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--id", default=None, help="trials id written to trials.toml (default: folder name)")
    p.set_defaults(func=_run_cli)


#: the option that sets each PoolSettings field (for a message about a bad value given on the command line)
_OPTION = {"models": "--models", "best": "--best", "fps": "--fps", "seed": "--seed", "width_px": "--size",
           "height_px": "--size"}


def _run_cli(args) -> int:
    from workbench.console import info
    from workbench.params import load_settings
    from workbench.virtual_lab.pool import generate_pool
    from workbench.virtual_lab.pool_trajectories import simulated_trials, synthetic_trials

    s = load_settings(PoolSettings, args.params, "pool")  # no --params: the built-in defaults
    changes: dict[str, Any] = {"trials_id": args.id or args.out.name}
    if args.models:
        changes["models"] = tuple(args.models)
    if args.best is not None:
        changes["best"] = args.best
    if args.fps is not None:
        changes["fps"] = args.fps
    if args.seed is not None:
        changes["seed"] = args.seed
    if args.size:
        try:
            w, h = (int(v) for v in args.size.lower().split("x"))
        except ValueError:
            raise SettingError(f"must look like 960x540, got {args.size!r}", where="--size") from None
        changes["width_px"], changes["height_px"] = w, h
    try:
        s = replace(s, **changes)
    except ParamsError as exc:  # the file's settings were checked; the fault is in the options given
        given = sorted({_OPTION.get(k, k) for k in changes if k != "trials_id"})
        raise SettingError(exc.fault, where=f"command line ({', '.join(given)})", hint=exc.hint) from None
    if args.synthetic:
        trials = synthetic_trials(s)
    else:
        gaits = args.gaits or Path("datasets/gaits")
        info(f"simulating the best {s.best} gaits of {', '.join(s.models)} for {', '.join(s.tasks)} "
             f"on '{s.physics}' physics")
        trials = simulated_trials(gaits, s)
    out = generate_pool(args.out, trials, settings=s)
    info(f"wrote {len(trials)} trials to {out} (truth in {out / 'truth.json'})")
    return 0
