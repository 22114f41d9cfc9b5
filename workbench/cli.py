"""The ``workbench`` command: one verb per module in ``workbench.commands``.

Each verb module defines ``register(subparsers)`` which adds its parser and sets
``func`` (called with the parsed arguments, returning an exit status or None). Verb modules
import heavy libraries (torch, lightning, mlflow, cv2) inside ``func`` only, so
``workbench --help`` answers in about a second.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from workbench import __version__
from workbench.errors import WorkbenchError

#: verb modules, in the order ``--help`` lists them (the data's way through the workbench)
VERB_MODULES = (
    "virtual_lab",
    "campaign",
    "acquire",
    "ingest",
    "interpolate",
    "fit_drag",
    "simulate",
    "train",
    "tune",
    "evaluate",
    "optimize",
    "sensitivity",
    "score_trials",
    "diagnose",
    "train_ensemble",
    "plan_campaign",
    "report",
    "ui",
)

EPILOG = """\
the daily loop:
  workbench virtual-lab tunnel datasets/raw/my-tunnel      # or drop a real campaign there
  workbench campaign add datasets/raw/my-tunnel           # validate, register, track with DVC
  dvc repro                                               # ingest, train, evaluate, optimise, ...
  workbench ui                                            # compare runs in the MLflow UI

Every verb has its own --help with examples. Data contract: docs/data-contract.md.
"""


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser with every available verb."""
    parser = argparse.ArgumentParser(
        prog="workbench",
        description="Hydrodynamics workbench for a swimming legged robot: rig logs in, "
        "validated Parquet, leg force models (EF, FED-LSTM), gait optimisation, pool-trial scoring "
        "and model diagnosis out.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"workbench {__version__}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB")
    for name in VERB_MODULES:
        modname = f"workbench.commands.{name}"
        try:
            module = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name == modname:
                continue  # verb not built yet
            raise
        module.register(sub)
    return parser


def _line_buffered() -> None:
    """Progress lines appear as they are printed, also under `dvc repro`, `make` or a log pipe.

    Python block-buffers a piped stdout, which held a stage's progress back until it ended.
    """
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.reconfigure(line_buffering=True)
        except (AttributeError, ValueError):  # replaced streams (pytest capture, StringIO)
            pass


def main(argv: list[str] | None = None) -> int:
    """Entry point; bad input ends with ``error: <one line>`` on stderr and exit status 2."""
    _line_buffered()
    if argv is None:  # the real command (tests call main(args) in their own process): SIGTERM and SIGHUP clean
        from workbench import procs  # up like Ctrl-C, and children started through procs die with the command

        procs.install()
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 0 if args.verb is None else 2
    try:
        rc = args.func(args)
    except WorkbenchError as exc:
        print(f"error: {exc.format()}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return int(rc or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
