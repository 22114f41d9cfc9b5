"""``workbench simulate``: swim gaits in the full-body simulator; trajectory Parquet, paths plot, summary."""

from __future__ import annotations

from workbench.commands._help import add_verb

_GAIT_KEYS = ("theta_h_min_deg", "theta_k_max_deg", "frequency_hz", "alpha_rad")


def register(sub) -> None:
    """Add the ``simulate`` verb."""
    p = add_verb(
        sub, "simulate", help="simulate gaits with the full-body model (any leg force model)",
        description="Swim one or more gaits from rest in the full-body simulator (four legs, HAA "
        "rotation, body drag, planar motion; docs/hydro.md). Gaits come from a gaits JSON file "
        "(data contract section 5) and/or --gait on the command line (contract parameter names; "
        "alpha_rad as four comma-separated phases LF,RF,LH,RH, or one for all legs). Writes "
        "OUT/trajectory.parquet (one row per gait and tick: pose, body velocities, total, body "
        "and per-leg wrenches), OUT/paths.png and OUT/summary.json. Robot constants and "
        "simulation settings (fixed-point scheme and tolerance): pipelines/robot.yaml. A gait whose "
        "fixed point did not converge is reported on the terminal, in summary.json (converged: false, "
        "unconverged) and dashed in paths.png.",
        examples="""\
  workbench simulate --gait theta_h_min_deg=-20 theta_k_max_deg=-50 frequency_hz=0.5 alpha_rad=0 --out /tmp/sim
  workbench simulate --gait theta_h_min_deg=10 theta_k_max_deg=-20 frequency_hz=0.6 alpha_rad=0,3.14,0,3.14 \\
      --duration 30 --out /tmp/sim
  workbench simulate --gaits datasets/gaits/straight-ef.json --rank 1 --rank 2 --out /tmp/straight
  workbench simulate --gaits datasets/gaits/turn-lstm.json --model lstm --out /tmp/turn-lstm
  workbench simulate --gaits datasets/gaits/straight-ef.json --drag datasets/drag/demo-towing/drag.json --out /tmp/s
""")
    p.add_argument("--gaits", metavar="JSON", help="gaits file (contract section 5)")
    p.add_argument("--rank", type=int, action="append", metavar="N",
                   help="only the solution(s) of this rank from --gaits (repeatable; default: all)")
    p.add_argument("--gait", nargs="+", action="append", metavar="KEY=VALUE",
                   help="a gait on the command line (repeat --gait for more)")
    p.add_argument("--model", default="ef", help="leg force model spec (default: ef; e.g. lstm, models:/name@alias)")
    p.add_argument("--robot", default="pipelines/robot.yaml", metavar="YAML",
                   help="robot constants and simulation settings (default: pipelines/robot.yaml)")
    p.add_argument("--drag", default=None, metavar="JSON", help="body drag from `workbench fit-drag` (drag.json)")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="simulated time (s)")
    p.add_argument("--dt", type=float, default=None, metavar="S", help="time step (s)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.set_defaults(func=run)


def parse_gait(tokens: list[str]) -> dict:
    """``KEY=VALUE`` tokens -> a gait ``params`` dict (contract names); a bad token is a SettingError."""
    from workbench.errors import SettingError

    params: dict = {}
    for tok in tokens:
        key, sep, value = tok.partition("=")
        if not sep or key not in _GAIT_KEYS:
            raise SettingError(f"expects KEY=VALUE with KEY in {list(_GAIT_KEYS)}, got {tok!r}", where="--gait")
        try:
            nums = [float(v) for v in value.split(",")]
        except ValueError:
            raise SettingError(f"{value!r} is not a number (or list of numbers)", where=f"--gait {key}") from None
        if key == "alpha_rad":
            if len(nums) not in (1, 4):
                raise SettingError("takes one phase or four (LF,RF,LH,RH)", where="--gait alpha_rad")
            params[key] = nums * 4 if len(nums) == 1 else nums
        elif len(nums) != 1:
            raise SettingError("takes one number", where=f"--gait {key}")
        else:
            params[key] = nums[0]
    missing = [k for k in _GAIT_KEYS if k not in params]
    if missing:
        raise SettingError(f"lacks {missing}", where="--gait")
    return params


def gait_batch(gaits: list[tuple[str, dict]], files: dict | None = None):
    """The :class:`GaitBatch` of labelled gaits; a bad value is a SettingError naming the gait and its file.

    ``files`` maps the label of each gait read from a file to that file (the command line's have none).
    """
    from workbench.errors import SettingError
    from workbench.hydro.simulator import GaitBatch

    try:
        return GaitBatch.from_params([p for _, p in gaits], labels=[label for label, _ in gaits])
    except SettingError as exc:
        raise exc.located(path=(files or {}).get(exc.where)) from None


def read_gaits_file(path, ranks: list[int] | None) -> list[tuple[str, dict]]:
    """(label, params) of the solutions in a gaits file (contract section 5), optionally some ranks."""
    from pathlib import Path

    from workbench.contract.jsonfile import read_json
    from workbench.errors import ContractError

    p = Path(path)
    doc = read_json(p, "gaits file")
    sols = doc.get("solutions") if isinstance(doc, dict) else None
    if not isinstance(sols, list) or not sols:
        raise ContractError("no 'solutions' list", path=p)
    out = []
    for i, sol in enumerate(sols):
        params = sol.get("params") if isinstance(sol, dict) else None
        if not isinstance(params, dict) or any(k not in params for k in _GAIT_KEYS):
            raise ContractError(f"solution #{i + 1} lacks params {list(_GAIT_KEYS)}", path=p)
        rank = sol.get("rank", i + 1)
        if ranks and rank not in ranks:
            continue
        alpha = params["alpha_rad"]
        if isinstance(alpha, list) and len(alpha) != 4:
            raise ContractError(f"solution rank {rank}: alpha_rad needs four phases LF,RF,LH,RH", path=p)
        out.append((f"{doc.get('task', 'gait')}-{doc.get('model', '?')} #{rank}", params))
    if not out:
        raise ContractError(f"no solution with rank {ranks}", path=p)
    return out


def robot_simulation_settings(robot: str) -> dict:
    """The robot file's optional ``simulation`` section, checked by the simulator (a bad value: ParamsError)."""
    from workbench.hydro.simulator import simulation_settings
    from workbench.params import read_section

    section, source = read_section(robot, "simulation", required=False)
    return simulation_settings(section, path=source)


def run(args) -> int:
    """Load gaits, robot and leg model, simulate the batch, write the outputs."""
    from pathlib import Path

    from workbench.atomic import atomic_dir, check_replaceable, write_json

    check_replaceable(args.out, "simulate")  # a wrong --out is refused before the work, not after

    from workbench.console import info
    from workbench.errors import ContractError
    from workbench.hydro.legmodel import load_leg_model
    from workbench.hydro.robot import load_robot
    from workbench.hydro.sim_report import paths_figure_png, summarise
    from workbench.hydro.simulator import simulate

    gaits: list[tuple[str, dict]] = read_gaits_file(args.gaits, args.rank) if args.gaits else []
    files = {label: args.gaits for label, _ in gaits}
    for i, tokens in enumerate(args.gait or []):
        gaits.append((f"gait {i + 1}", parse_gait(tokens)))
    if not gaits:
        raise ContractError("no gait given", hint="use --gaits FILE and/or --gait KEY=VALUE ...")
    batch = gait_batch(gaits, files)
    robot = load_robot(args.robot, drag_json=args.drag)
    settings = robot_simulation_settings(args.robot)
    if args.duration is not None:
        settings["duration_s"] = args.duration
    if args.dt is not None:
        settings["dt_s"] = args.dt
    model = load_leg_model(args.model)
    labels = [label for label, _ in gaits]
    info(f"simulating {len(batch)} gait(s) with leg model {args.model!r} for {settings.get('duration_s', 20.0):g} s")
    traj = simulate(batch, model, robot, **settings,
                    on_iteration=lambda k, res: info(f"  leg-model call {k}: largest flow change "
                                                     f"{res.max():.2e} m/s"))
    tol = settings.get("tol_mps", 1e-5)
    bad = [i for i in range(len(labels)) if not traj.converged[i]]
    for i in bad:
        info(f"warning: {labels[i]}: the simulation did NOT converge (fixed-point residual "
             f"{traj.residual_mps[i]:.2g} m/s > {tol:g}); its trajectory is not a solution (summary.json: "
             f"converged false; dashed in paths.png)")
    frame = traj.to_frame([{"label": lab} for lab in labels])
    summary = {"model": args.model, "robot": robot.describe(), "settings": settings,
               "iterations": traj.iterations, "converged_all": not bad,
               "unconverged": [labels[i] for i in bad], "gaits": summarise(traj, labels)}
    png = paths_figure_png(traj, labels)
    out = Path(args.out)
    with atomic_dir(out, verb="simulate") as tmp:  # the three files are one set, swapped in together
        frame.write_parquet(tmp / "trajectory.parquet")
        (tmp / "paths.png").write_bytes(png)
        write_json(tmp / "summary.json", summary)
    for g in summary["gaits"]:
        info(f"{g['gait']}: end ({g['final_x_m']:+.3f}, {g['final_y_m']:+.3f}) m, yaw {g['final_yaw_deg']:+.1f} deg, "
             f"forward speed {g['mean_forward_speed_mps']:.3f} m/s")
    info(f"wrote {out / 'trajectory.parquet'}, paths.png, summary.json")
    if bad:
        info(f"warning: {len(bad)} of {len(labels)} gait(s) did not converge (see above)")
    return 0
