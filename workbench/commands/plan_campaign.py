"""``workbench plan-campaign``: propose the next tunnel campaign (contract section 6)."""

from __future__ import annotations

from workbench.commands._help import add_verb

EXAMPLES = """\
  # 12 runs that most reduce the FED-LSTM ensemble's uncertainty where the retained gaits swim,
  # plus the runs the diagnosis asks for; writes the manifest and plan.md beside it
  workbench plan-campaign --model datasets/models/fed-lstm-ensemble \\
      --gaits datasets/gaits/straight-lstm.json datasets/gaits/turn-lstm.json \\
      --diagnosis datasets/diagnosis/demo-tunnel-ef --n-runs 12 --out datasets/plans/next-campaign.toml

  # measure it in the virtual tunnel (or hand the manifest to the rig's controller), then add it
  workbench virtual-lab tunnel datasets/raw/next-campaign --plan datasets/plans/next-campaign.toml
  workbench campaign add datasets/raw/next-campaign

  # cheaper runs: 3 cycles each, a longer setup per run, only the best gait of each file
  workbench plan-campaign --model ENS --gaits datasets/gaits/*-lstm.json --n-runs 8 --out /tmp/p.toml \\
      --set ranges.cycles=3 --set ranges.setup_s=120 --set max_rank=1
"""


def register(sub) -> None:
    """Add the ``plan-campaign`` verb."""
    from pathlib import Path

    p = add_verb(sub, "plan-campaign", help="propose the next tunnel campaign (runs that teach the models most)",
                 description="Propose N tunnel runs (motion parameters within the rig's ranges, flow speed, cycles) "
                             "that most reduce the FED-LSTM ensemble's uncertainty at the states the retained gaits "
                             "put the legs in (the operating region, from full-body swims of the gaits): greedy "
                             "integrated posterior variance over the ensemble, per second of tunnel time. With "
                             "--diagnosis, runs that separate effects the diagnosis calls ambiguous come first. "
                             "Writes a contract-v1 campaign.toml whose runs have no files yet (they are to be "
                             "measured) and plan.md beside it: why each run, its expected gain, the tunnel time. "
                             "See docs/campaigns.md.",
                 examples=EXAMPLES)
    p.add_argument("--model", required=True, type=Path, metavar="ENSEMBLE_DIR",
                   help="ensemble folder written by `workbench train-ensemble` (ensemble.json + members)")
    p.add_argument("--gaits", required=True, nargs="+", type=Path, metavar="GAIT_FILE",
                   help="retained gaits, datasets/gaits/<task>-<model>.json (contract section 5)")
    p.add_argument("--n-runs", required=True, type=int, metavar="N", help="runs to propose (besides the diagnosis's)")
    p.add_argument("--out", required=True, type=Path, metavar="PLAN.toml", help="the manifest to write; plan.md "
                                                                               "goes beside it")
    p.add_argument("--diagnosis", type=Path, metavar="DIR", help="a `workbench diagnose` folder (or diagnosis.json): "
                   "effects flagged ambiguous_with get runs that tell them apart")
    p.add_argument("--params", type=Path, default=Path("pipelines/plan.yaml"),
                   help="YAML with a 'plan' section (default: %(default)s)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a key of the plan section, e.g. --set ranges.cycles=3 (repeatable)")
    p.add_argument("--id", help="campaign id of the plan (default: from the --out file name)")
    p.add_argument("--date", help="date of the manifest, YYYY-MM-DD (default: today)")
    p.add_argument("--robot", type=Path, default=Path("pipelines/robot.yaml"), help="robot constants for the swims")
    p.add_argument("--drag", type=Path, help="drag.json of the body (workbench fit-drag) for the swims")
    p.set_defaults(func=run)


def _settings(args):
    import yaml

    from workbench.errors import ContractError
    from workbench.plan.planner import PlanSettings
    from workbench.project import load_params

    doc = dict(load_params(args.params, "plan") or {}) if args.params.exists() else {}
    for item in args.set:
        key, sep, value = item.partition("=")
        if not sep:
            raise ContractError(f"--set {item!r} is not key=value", hint="e.g. --set ranges.cycles=3")
        node = doc
        parts = key.strip().split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = yaml.safe_load(value)
    return PlanSettings.from_dict(doc)


def run(args) -> int:
    """Plan and report."""
    from workbench.console import info
    from workbench.plan.planner import plan_campaign

    rec = plan_campaign(args.model, args.gaits, args.n_runs, args.out, diagnosis=args.diagnosis,
                        settings=_settings(args), campaign_id=args.id, date=args.date, robot_yaml=args.robot,
                        drag_json=args.drag)
    drop = 100 * (1 - rec["total_after"] / max(rec["total_before"], 1e-30))
    info(f"planned {rec['n_runs']} runs ({rec['n_diagnosis_runs']} for the diagnosis), "
         f"{rec['tunnel_s'] / 60:.1f} tunnel minutes; region-weighted variance {drop:.0f} % lower expected")
    info(f"wrote {args.out} (files pending) and {args.out.with_name('plan.md')} in {rec['cost_s']['total']:.0f} s")
    return 0
