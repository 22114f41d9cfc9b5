"""``workbench sensitivity``: Sobol indices of gait scores and ranking over the estimated robot constants."""

from __future__ import annotations

from workbench.commands._help import add_verb


def register(sub) -> None:
    """Add the ``sensitivity`` verb."""
    p = add_verb(
        sub, "sensitivity", help="how much the estimated robot constants move the gait scores and ranking",
        description="Vary the robot constants the paper does not give (added masses, yaw inertia, yaw "
        "damping, drag below the towed speed range; ranges in workbench/gait/sensitivity.py, docs/"
        "sensitivity.md) over plausible ranges, swim the retained gaits of a gaits file in the full-body "
        "simulator, score them on the task they were optimised on and compute Sobol indices "
        "(scipy.stats.sobol_indices) of each gait's score and of the ranking (Kendall tau against the "
        "nominal robot). N base samples cost N x 8 simulations of the batch. Writes OUT/sensitivity.json "
        "and OUT/sensitivity.png. Unconverged simulations are counted, never scored.",
        examples="""\
  workbench sensitivity --gaits datasets/gaits/turn-ef.json --out datasets/reports/sensitivity/turn-ef
  workbench sensitivity --gaits datasets/gaits/straight-ef.json --best 4 --n 32 --out /tmp/sens
  workbench sensitivity --gaits datasets/gaits/turn-lstm.json --model lstm --n 8 --out /tmp/sens-lstm
""")
    p.add_argument("--gaits", required=True, metavar="JSON", help="gaits file (contract section 5)")
    p.add_argument("--best", type=int, default=8, metavar="K", help="the K best-ranked solutions (default 8)")
    p.add_argument("--n", type=int, default=16, metavar="N", help="Sobol base samples, a power of 2 (default 16)")
    p.add_argument("--model", default="ef", help="leg force model spec (default: ef)")
    p.add_argument("--robot", default="pipelines/robot.yaml", metavar="YAML", help="nominal robot constants")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(func=run)


def run(args) -> int:
    """Load the gaits, robot and leg model; run the study; write JSON and figure."""
    from pathlib import Path

    from workbench.atomic import atomic_dir, check_replaceable, write_json

    check_replaceable(args.out, "sensitivity")  # a wrong --out is refused before the work, not after

    from workbench.commands.simulate import gait_batch, read_gaits_file, robot_simulation_settings
    from workbench.console import info
    from workbench.contract.jsonfile import read_json
    from workbench.errors import ContractError
    from workbench.gait.objectives import TaskSpec
    from workbench.gait.sensitivity import FACTORS, figure_png, run_sensitivity
    from workbench.hydro.legmodel import load_leg_model
    from workbench.hydro.robot import load_robot
    from workbench.hydro.simulator import simulation_settings

    gaits = read_gaits_file(args.gaits, None)[: max(args.best, 2)]
    doc = read_json(Path(args.gaits), "gaits file")
    task_doc = (doc.get("settings") or {}).get("task")
    if not isinstance(task_doc, dict) or "task" not in task_doc:
        raise ContractError("no settings.task (the task the gaits were optimised on)", path=args.gaits)
    # a bad setting or gait value is a ParamsError/SettingError naming the file and the key or gait
    spec = TaskSpec.from_dict(task_doc["task"], task_doc, key="settings.task", path=str(args.gaits))
    batch = gait_batch(gaits, {label: args.gaits for label, _ in gaits})
    settings = robot_simulation_settings(args.robot)
    settings["duration_s"] = spec.cap_s
    # the scheme the gaits were optimised with (checked: a bad value names the gaits file and its key)
    stored = (doc.get("settings") or {}).get("simulation") or {}
    settings.update(simulation_settings({k: v for k, v in (stored.items() if isinstance(stored, dict) else ())
                                         if k in ("dt_s", "tol_mps", "max_iter", "relaxation")},
                                        path=args.gaits, key="settings.simulation"))
    robot = load_robot(args.robot)
    model = load_leg_model(args.model)
    total = args.n * (len(FACTORS) + 2)
    info(f"{len(gaits)} {spec.task} gaits, {len(FACTORS)} factors, {total} simulations of {spec.cap_s:g} s")
    step = max(total // 10, 1)
    result = run_sensitivity(batch, [lab for lab, _ in gaits], model, robot, spec, n=args.n, seed=args.seed,
                             settings=settings,
                             progress=lambda k: info(f"  {k}/{total} simulations") if k % step == 0 else None)
    out = Path(args.out)
    summary = result.to_dict() | {"gaits_file": str(args.gaits), "model": args.model, "robot": str(args.robot)}
    with atomic_dir(out, verb="sensitivity") as tmp:  # indices and figure are one set
        write_json(tmp / "sensitivity.json", summary)
        (tmp / "sensitivity.png").write_bytes(figure_png(result))
    r = summary["ranking"]
    info(f"ranking: Kendall tau min {r['kendall_tau_min']:.2f}, mean {r['kendall_tau_mean']:.2f}; nominal best "
         f"stays best in {100 * r['nominal_best_stays_best_fraction']:.0f}% of the samples")
    if result.unconverged:
        info(f"warning: unconverged samples (no indices): {result.unconverged}")
    info(f"wrote {out / 'sensitivity.json'} and sensitivity.png")
    return 0
