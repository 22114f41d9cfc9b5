"""``workbench virtual-lab``: write virtual tunnel and towing-tank campaigns, list the injectable effects."""

from __future__ import annotations

import argparse
from pathlib import Path

from workbench.commands._help import add_verb

EXAMPLES = """\
  workbench virtual-lab tunnel datasets/raw/t1                         # demo scale, CSV pairs, seed 0
  workbench virtual-lab tunnel datasets/raw/t1 --form mcap --effect servo_lag:tau_s=0.04
  workbench virtual-lab tunnel datasets/raw/t-ef --truth ef --seed 3   # truth = the paper's EF exactly
  workbench virtual-lab tunnel datasets/raw/big --scale paper --form bin   # 1920 runs, ~3 M ticks
  workbench virtual-lab tunnel datasets/raw/demo-tunnel --params pipelines/virtual_lab.yaml
  workbench virtual-lab towing datasets/raw/demo-towing --params pipelines/virtual_lab.yaml
  workbench virtual-lab effects                                         # every effect, physics, parameters
"""

TUNNEL_EXAMPLES = """\
  workbench virtual-lab tunnel datasets/raw/t1
  workbench virtual-lab tunnel datasets/raw/t2 --form mixed --feedback --seed 7
  workbench virtual-lab tunnel datasets/raw/t3 --effect servo_lag:tau_s=0.04 \\
      --effect loadcell_crosstalk:x_fy_fz=0.03,x_fz_fy=0.02 --effect electrical_pickup:f_hz=2.7
  workbench virtual-lab tunnel datasets/raw/t4 --flow-speeds 0 0.2 --cycles 3 --truth ef
  workbench virtual-lab tunnel datasets/raw/demo-tunnel --params pipelines/virtual_lab.yaml
  workbench virtual-lab tunnel datasets/raw/next-1 --plan datasets/plans/next-campaign.toml   # a plan's runs
"""

TOWING_EXAMPLES = """\
  workbench virtual-lab towing datasets/raw/tow1
  workbench virtual-lab towing datasets/raw/tow2 --scale paper --form mcap
  workbench virtual-lab towing datasets/raw/tow3 --speeds 0.1 0.2 0.3 --seed 4
"""

def register(sub) -> None:
    """Add ``virtual-lab`` with its subcommands."""
    p = add_verb(sub, "virtual-lab", help="write virtual tunnel / towing-tank campaigns (no hardware needed)",
                 description="The virtual lab writes campaign folders exactly per the data contract, with "
                 "physics richer than the models under test, a rig with its own clocks, noise, bias and "
                 "drift, and named effects to plant. Every folder also holds truth.json (ground truth). "
                 "See docs/virtual-lab.md.", examples=EXAMPLES)
    p.set_defaults(func=lambda args: (p.print_help(), 0)[1])
    vsub = p.add_subparsers(dest="lab", metavar="WHAT")

    t = vsub.add_parser("tunnel", help="a water-tunnel campaign (prescribed leg motion, paper eq. 3)",
                        description="Write a water-tunnel campaign: the paper's prescribed leg motion at each "
                        "flow speed, the ground-truth wrench, the rig's clocks, trigger line and load cell.",
                        epilog="examples:\n" + TUNNEL_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    t.add_argument("out", type=Path, metavar="DIR", help="campaign folder (its name is the campaign id)")
    t.add_argument("--params", type=Path, help="YAML with a 'tunnel' section (pipelines/virtual_lab.yaml)")
    t.add_argument("--scale", choices=("demo", "paper"), help="demo: 48 sets x 5 cycles per speed; paper: 480 x 10")
    t.add_argument("--seed", type=int, help="random seed (same seed, same bytes)")
    t.add_argument("--form", choices=("csv", "bin", "mcap", "mixed"), help="raw file form (mixed: all three)")
    t.add_argument("--truth", choices=("rich", "ef"), help="ground truth: rich physics (default) or exactly the EF")
    t.add_argument("--effect", action="append", metavar="SPEC", help="plant an effect, e.g. servo_lag:tau_s=0.04 "
                   "(repeatable; see 'workbench virtual-lab effects')")
    t.add_argument("--flow-speeds", type=float, nargs="+", metavar="U", help="flow speeds in m/s (default 0 0.1 0.2 0.3)")
    t.add_argument("--cycles", type=int, help="cycles per run (default: the scale's)")
    t.add_argument("--feedback", action=argparse.BooleanOptionalAction, default=None,
                   help="motion logs carry measured angles ([motion] feedback)")
    t.add_argument("--bin-faults", action="store_true", default=None,
                   help="the first .bin capture starts mid-frame, has bad/dropped bytes and a counter wrap")
    t.add_argument("--plan", type=Path, metavar="PLAN.toml",
                   help="measure exactly the runs of a planned campaign (workbench plan-campaign): same ids, flow "
                        "speeds, parameters and cycles; --scale, --flow-speeds and --cycles do not apply")
    t.set_defaults(func=_tunnel)

    w = vsub.add_parser("towing", help="a towing-tank campaign (body drag, paper's quadratic fits)",
                        description="Write a towing-tank campaign: the robot towed forward (+y) and sideways "
                        "(+x) at constant speeds with acceleration and deceleration phases.",
                        epilog="examples:\n" + TOWING_EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    w.add_argument("out", type=Path, metavar="DIR", help="campaign folder (its name is the campaign id)")
    w.add_argument("--params", type=Path, help="YAML with a 'towing' section (pipelines/virtual_lab.yaml)")
    w.add_argument("--scale", choices=("demo", "paper"), help="demo: 8 speeds x 2 headings; paper: 11 x 2 x 3")
    w.add_argument("--seed", type=int, help="random seed")
    w.add_argument("--form", choices=("csv", "bin", "mcap", "mixed"), help="raw file form")
    w.add_argument("--speeds", type=float, nargs="+", metavar="V", help="carriage speeds in m/s")
    w.set_defaults(func=_towing)

    e = vsub.add_parser("effects", help="list the effects the virtual lab can plant",
                        description="Every named effect with where it acts, its physics and its parameters.",
                        epilog="examples:\n  workbench virtual-lab effects\n  workbench virtual-lab effects --json\n",
                        formatter_class=argparse.RawDescriptionHelpFormatter)
    e.add_argument("--json", action="store_true", help="machine-readable output")
    e.set_defaults(func=_effects)

    try:
        from workbench.virtual_lab import pool
    except ModuleNotFoundError as exc:
        if exc.name != "workbench.virtual_lab.pool":
            raise
    else:
        pool.add_cli(vsub)


def _section(path: Path | None, name: str):
    """The section's campaign settings and rig settings (workbench.params; unknown keys refused)."""
    from workbench.params import read_section
    from workbench.virtual_lab.settings import campaign_and_rig

    raw, source = read_section(path, name)
    return campaign_and_rig(raw, name, source)


def _pick(cli, yaml_value, default):
    return cli if cli is not None else (yaml_value if yaml_value is not None else default)


def _summary(out: Path, kind: str, seconds: float) -> None:
    import json

    from workbench.console import info

    truth = json.loads((out / "truth.json").read_text(encoding="utf-8"))
    size = sum(f.stat().st_size for f in out.rglob("*") if f.is_file())
    info(f"wrote {out}: {kind}, {len(truth['runs'])} runs, {size / 1e6:.1f} MB in {seconds:.1f} s "
         f"(seed {truth['seed']}, form {truth['form']})")


def _tunnel(args) -> int:
    import time

    from workbench.virtual_lab.tunnel import generate_tunnel

    gen, rig = _section(args.params, "tunnel")
    t0 = time.perf_counter()
    out = generate_tunnel(
        args.out, scale=_pick(args.scale, gen.scale, "demo"), seed=_pick(args.seed, gen.seed, 0),
        form=_pick(args.form, gen.form, "csv"), truth=_pick(args.truth, gen.truth, "rich"),
        effects=[*gen.effects, *(args.effect or [])], flow_speeds=_pick(args.flow_speeds, gen.flow_speeds_mps, None),
        grid=gen.grid, cycles=_pick(args.cycles, gen.cycles, None), feedback=_pick(args.feedback, gen.feedback, None),
        bin_faults=bool(_pick(args.bin_faults, gen.bin_faults, False)), settings=rig, show_progress=True,
        plan=getattr(args, "plan", None))
    _summary(out, "water tunnel", time.perf_counter() - t0)
    return 0


def _towing(args) -> int:
    import time

    from workbench.virtual_lab.towing import HEADINGS, generate_towing

    gen, rig = _section(args.params, "towing")
    t0 = time.perf_counter()
    out = generate_towing(
        args.out, scale=_pick(args.scale, gen.scale, "demo"), seed=_pick(args.seed, gen.seed, 0),
        form=_pick(args.form, gen.form, "csv"), speeds=_pick(args.speeds, gen.speeds_mps, None),
        headings=gen.headings or HEADINGS, repeats=gen.repeats, settings=rig, show_progress=True)
    _summary(out, "towing tank", time.perf_counter() - t0)
    return 0


def _effects(args) -> int:
    import json
    import textwrap

    from workbench.virtual_lab.effects import describe_all

    items = describe_all()
    if args.json:
        print(json.dumps(items, indent=2))
        return 0
    for e in items:
        print(f"{e['name']}  [{e['stage']}]")
        print(textwrap.fill(e["physics"], width=96, initial_indent="    ", subsequent_indent="    "))
        for k, p in e["params"].items():
            unit = f" {p['unit']}" if p["unit"] else ""
            print(f"      {k} = {p['default']}{unit}: {p['help']}")
        example = e["name"] + (":" + ",".join(f"{k}={p['default']}" for k, p in e["params"].items() if "<" not in k)
                               if any("<" not in k for k in e["params"]) else "")
        print(f"    e.g. --effect {example}")
        print()
    return 0
