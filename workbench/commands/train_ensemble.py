"""``workbench train-ensemble``: a deep ensemble of FED-LSTMs with a calibrated 90 % interval per channel."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from workbench.commands._help import add_verb

EXAMPLES = """\
  # the pipeline's ensemble (pipelines/plan.yaml, section ensemble) on the interpolated demo campaign
  workbench train-ensemble --data datasets/processed/interp --out datasets/models/fed-lstm-ensemble \\
      --params pipelines/plan.yaml --no-mlflow

  # five members of the full demo-sized training (pipelines/learn.yaml as it is)
  workbench train-ensemble --data datasets/processed/interp --members 5 --out /tmp/ens --no-mlflow

  # then: the calibration it measured (coverage of the 90 % interval, per channel, on held-out sets)
  python -c "import json; print(json.load(open('/tmp/ens/ensemble.json'))['calibration'])"
"""


@dataclass(frozen=True)
class EnsembleSettings:
    """The ``ensemble`` section of pipelines/plan.yaml (``--params``)."""

    #: members trained through ``train(cfg)``, seeds first_seed .. first_seed + members - 1
    members: int = 4
    first_seed: int = 0
    #: dotted-key overrides of pipelines/learn.yaml's train section for the members
    train: Mapping[str, Any] = field(default_factory=dict)


def register(sub) -> None:
    """Add the ``train-ensemble`` verb."""
    from pathlib import Path

    from workbench.learn.config import add_common_options

    p = add_verb(sub, "train-ensemble", help="train a FED-LSTM deep ensemble (uncertainty for plan-campaign)",
                 description="Train K FED-LSTMs through the same training as `workbench train` (same data and split, "
                             "seeds first_seed..first_seed+K-1), then fit each channel's residual noise and a 90 % "
                             "interval scale on the validation split and measure the interval's coverage on the "
                             "held-out test split (before and after that calibration). Writes DIR/ensemble.json and "
                             "DIR/member-XX/ model folders. docs/campaigns.md explains how plan-campaign uses it.",
                 examples=EXAMPLES)
    add_common_options(p)
    p.add_argument("--out", required=True, metavar="DIR", help="ensemble folder to write")
    p.add_argument("--params", type=Path, help="YAML with an 'ensemble' section (pipelines/plan.yaml): members, "
                                               "first_seed and train overrides")
    p.add_argument("--members", type=int, help="number of members K (default: the params', else 4)")
    p.add_argument("--quiet", action="store_true", help="no per-epoch lines")
    p.set_defaults(func=run)


def run(args) -> int:
    """Train, calibrate, report."""
    from workbench.console import info
    from workbench.learn.config import cli_config
    from workbench.learn.ensemble import train_ensemble
    from workbench.params import load_settings

    sec = load_settings(EnsembleSettings, args.params, "ensemble")  # no --params: the defaults
    cfg = cli_config(args)
    over = dict(sec.train)
    # command-line --set wins over the ensemble section
    for s in args.set or ():
        over.pop(s.partition("=")[0].strip(), None)
    if over:
        cfg = cfg.with_overrides(over)
    members = args.members or sec.members
    from workbench.atomic import check_replaceable

    check_replaceable(args.out, "train-ensemble")
    info(f"train-ensemble: {members} x {cfg.model.variant} {cfg.model.hidden_size}x{cfg.model.num_layers}, "
         f"{cfg.trainer.max_epochs} epochs, data {', '.join(cfg.data.paths)}")
    rec, files = train_ensemble(cfg, members=members, first_seed=sec.first_seed,
                                report=None if args.quiet else info)
    write_ensemble(args.out, files)
    cal = rec["calibration"]
    for key in ("coverage_test_before", "coverage_test_after"):
        if key in cal:
            info(f"90 % interval coverage, test ({key.rsplit('_', 1)[1]} calibration): "
                 + "  ".join(f"{c} {100 * v:.0f} %" for c, v in cal[key].items()))
    info(f"ensemble folder: {args.out} ({rec['cost_s']['total']:.0f} s)")
    return 0


def write_ensemble(target, files: dict[str, bytes]):
    """Write an ensemble folder (:func:`workbench.learn.ensemble.train_ensemble`'s files: relative name -> bytes).

    One set: built beside ``target`` and swapped in whole (:func:`workbench.atomic.atomic_dir`): a kill
    leaves the previous ensemble or the new one, never members of one with the other's ensemble.json.
    """
    from pathlib import Path

    from workbench.atomic import atomic_dir

    with atomic_dir(target, verb="train-ensemble") as tmp:
        for name, data in files.items():
            path = Path(tmp) / name
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
    return Path(target)
