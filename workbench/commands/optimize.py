"""``workbench optimize``: NSGA-II gait optimisation (paper section IV) for one task and one leg model."""

from __future__ import annotations

from workbench.commands._help import add_verb


def register(sub) -> None:
    """Add the ``optimize`` verb."""
    p = add_verb(
        sub, "optimize", help="optimise gaits with NSGA-II in the full-body simulator (straight or turn)",
        description="Search the paper's gait parameters (Table II: theta_h_min, theta_k_max, f, one phase per "
        "leg) with NSGA-II, minimising the task's three objectives (Table III) in the full-body simulator "
        "with the chosen leg force model; rank the final population by S = w1 f1 + w2 f2 + w3 f3 and keep "
        "the best (8). Writes OUT/<task>-<model>.json (data contract section 5), OUT/<task>-<model>/ "
        "(controller.json for the robot, best.csv, history.csv, population.csv, pareto.png, "
        "hypervolume.png, trajectories.png) and OUT/<task>-<model>.metrics.json, and logs an MLflow run "
        "(experiment 'optimize'). Models with memory (the FED-LSTM) are served from per-gait tables of "
        "one steady cycle over a flow-speed grid (docs/gaits.md). The default tasks are the pool trials' "
        "(straight: 2 m within 60 s; turn: 360 deg within 60 s; f3 the time to finish). A gait whose "
        "simulation did not converge is penalised (ranked below every converged one) and counted "
        "(unconverged_gaits in the gait and metrics files and MLflow). Every constant: pipelines/gait.yaml "
        "(space.extension: per_side_range adds per-side joint ranges, which turn; docs/gaits.md). "
        "Pipeline stages name a learned model by its saved folder (--model datasets/models/fed-lstm --label "
        "lstm): a path is a DVC dependency, a registry alias is not. A registry spec (lstm, models:/...) "
        "is resolved here and the version used is printed and recorded (gait file: model_source; MLflow tags "
        "model_uri, model_version, model_path).",
        examples="""\
  workbench optimize --task straight --model ef --params pipelines/gait.yaml --out datasets/gaits
  workbench optimize --task turn --model lstm --out /tmp/gaits          # prints the registry version it used
  workbench optimize --task straight --model datasets/models/fed-lstm-16 --label lstm16 --out /tmp/gaits
  workbench optimize --task straight --model models:/fed-lstm@tuned --pop 64 --gens 50 --seed 3 --out /tmp/gaits
  workbench optimize --task turn --model ef --drag datasets/drag/demo-towing/drag.json --no-mlflow --out /tmp/g
  workbench optimize --task turn --model ef --workers 2 --out /tmp/g    # 2 simulator processes, same results
  workbench simulate --gaits datasets/gaits/straight-ef.json --rank 1 --out /tmp/best   # swim the winner
""")
    p.add_argument("--task", required=True, choices=("straight", "turn"), help="what the robot should do")
    p.add_argument("--model", default="ef", help="leg force model: ef, lstm (registered FED-LSTM champion), "
                   "models:/name@alias, models:/name/VERSION, a saved model folder (e.g. datasets/models/fed-lstm), "
                   "or any registered spec (default: ef)")
    p.add_argument("--label", default=None, metavar="NAME",
                   help="name of the results: OUT/<task>-NAME.json, .metrics.json, the folder and the gait file's "
                        "model field (letters, digits, - and _; default: derived from --model: ef, lstm, "
                        "models:/fed-lstm@tuned -> fed-lstm-tuned, a folder -> its name)")
    p.add_argument("--params", default="pipelines/gait.yaml", metavar="YAML",
                   help="parameter file, section 'optimize' (default: pipelines/gait.yaml)")
    p.add_argument("--out", default="scratch/gaits", metavar="DIR",
                   help="output folder (default: scratch/gaits; the pipeline's stages write datasets/gaits)")
    p.add_argument("--pop", type=int, default=None, metavar="N", help="population size (overrides the file)")
    p.add_argument("--gens", type=int, default=None, metavar="N", help="generations (overrides the file)")
    p.add_argument("--seed", type=int, default=None, metavar="N", help="random seed (overrides the file)")
    p.add_argument("--workers", default=None, metavar="N|auto",
                   help="simulator processes, each swimming its share of every population and of the direct check; "
                        "the results do not depend on it (default: the file's 'workers'; auto: the cores idle now)")
    p.add_argument("--robot", default=None, metavar="YAML", help="robot constants (default: the file's 'robot')")
    p.add_argument("--drag", default=None, metavar="JSON", help="body drag from `workbench fit-drag` (drag.json)")
    p.add_argument("--no-mlflow", action="store_true", help="do not log an MLflow run")
    p.add_argument("--tracking-uri", default=None, metavar="URI", help="MLflow store (default: the project's)")
    p.set_defaults(func=run)


def _progress_printer(n_gen: int):
    """A per-generation progress display: a bar on a terminal, one line per generation elsewhere."""
    import sys
    from contextlib import ExitStack

    from workbench.console import info, progress

    stack = ExitStack()
    if sys.stderr.isatty():
        task = stack.enter_context(progress("optimising", total=n_gen, unit=" generations"))

        def show(g):
            task.advance(1, status=f"evals {g.evaluations}  best S {g.best_score:.3f}  HV {g.hypervolume:.4g}")
    else:
        def show(g):
            info(f"  gen {g.gen:3d}/{n_gen}  evals {g.evaluations:5d}  best S {g.best_score:9.4f}  "
                 f"HV {g.hypervolume:.5g}  ({g.seconds:.1f} s)")
    return stack, show


def _csv(rows: list[dict]) -> str:
    import io

    import polars as pl

    buf = io.StringIO()
    pl.DataFrame(rows).write_csv(buf)
    return buf.getvalue()


def run(args) -> int:
    """Load settings, robot and model; optimise; write the results atomically; log to MLflow."""
    import sys
    from pathlib import Path

    from workbench.console import info
    from workbench.gait.export import model_source, model_source_line
    from workbench.gait.optimize import optimize_task
    from workbench.hydro.legmodel import load_leg_model
    from workbench.hydro.robot import load_robot

    cfg = _settings(args)
    ts = cfg.task(args.task)
    robot = load_robot(args.robot or cfg.robot, drag_json=args.drag or cfg.drag_json)
    label = _label(args.label, args.model)
    from workbench.atomic import check_replaceable

    check_replaceable(Path(args.out) / f"{args.task}-{label}", "optimize")  # refused before the work, not after
    model = load_leg_model(args.model)
    if "torch" in sys.modules:  # a learned leg model
        from workbench.threads import apply_torch_threads

        apply_torch_threads(cfg.torch_threads)
    source = model_source(model)  # the registry version (or folder) the spec resolved to
    line = model_source_line(args.model, model)
    if line:
        info(line)
    from workbench.gait.workers import resolve_workers

    workers = resolve_workers(cfg.workers)
    info(f"optimising {args.task} gaits with leg model {args.model!r}: NSGA-II population {cfg.nsga2.pop_size}, "
         f"{cfg.nsga2.n_gen} generations, seed {cfg.nsga2.seed}, {ts.spec.cap_s:g} s swims, "
         f"{workers} simulator process{'es' if workers > 1 else ''}")
    stack, show = _progress_printer(cfg.nsga2.n_gen)
    with stack:
        outcome = optimize_task(cfg, args.task, model, robot, model_label=label, model_spec=args.model,
                                on_generation=show, workers=workers)
    m = outcome.metrics
    if source:  # which registry version or folder the results come from (issue 15.1)
        outcome.gait_doc["model_source"] = source
        m["model_source"] = source
    _warn_unconverged(m)
    folder, gaits_path, metrics_path = _write_results(Path(args.out), f"{args.task}-{label}", cfg, outcome)
    _print_summary(m, gaits_path, metrics_path, folder)
    if cfg.tracking.enabled and not args.no_mlflow:
        _log_to_mlflow(args, cfg, outcome, workers, folder, [gaits_path, metrics_path], source, model, robot)
    return 0


def _settings(args):
    """The gait settings of ``--params`` with the command line's overrides; a bad option is a ``SettingError``."""
    from workbench.errors import ParamsError, SettingError
    from workbench.gait.config import load_config

    cfg = load_config(args.params)
    try:
        cfg = cfg.with_overrides(pop_size=args.pop, n_gen=args.gens, seed=args.seed)
    except ParamsError as exc:  # the file's value was fine, the command line's is not: name the options
        raise SettingError(exc.fault, where="--pop/--gens/--seed", hint=exc.hint) from None
    try:
        return cfg.with_workers(args.workers)
    except ParamsError as exc:
        raise SettingError(exc.fault, where="--workers", hint=exc.hint) from None


def _warn_unconverged(m: dict) -> None:
    """Warn about simulated and retained gaits that did not converge."""
    from workbench.console import info

    if m["unconverged_gaits"]:
        info(f"warning: {m['unconverged_gaits']} of {m['simulated_gaits']} simulated gait(s) did not converge "
             f"(penalised: ranked below every converged gait; counted in the gait file and MLflow)")
    if m.get("retained_unconverged"):
        info(f"warning: {m['retained_unconverged']} retained gait(s) did not converge (marked converged: false "
             f"in the gait file; the virtual pool refuses them)")


def _population_rows(cfg, result) -> list[dict]:
    """One row per evaluated gait of the final population: its variables, objectives, score and convergence."""
    return [dict(zip(cfg.space.variables, map(float, x), strict=True)) | {"f1": float(f[0]), "f2": float(f[1]),
            "f3": float(f[2]), "score": float(s), "converged": bool(ok)}
            for x, f, s, ok in zip(result.x, result.f, result.s, result.converged, strict=True)]


def _write_results(out, stem: str, cfg, outcome):
    """Write the results folder ``out/stem`` and the gait and metrics files beside it as one set; their paths."""
    from dataclasses import asdict

    from workbench.atomic import atomic_files, json_text

    folder = out / stem
    history = [asdict(g) for g in outcome.result.history]
    population = _population_rows(cfg, outcome.result)
    metrics_path = out / f"{stem}.metrics.json"
    gaits_path = out / f"{stem}.json"
    # the folder and the two files beside it are one set: all three from this run or all from the last
    with atomic_files(out, [metrics_path.name, gaits_path.name], "optimize", dirs=[stem], set_name=f"optimize-{stem}",
                      recognise=_ours) as tmp:
        part = tmp[stem]
        (part / "controller.json").write_text(_json(outcome.controller_doc), encoding="utf-8")
        (part / "best.csv").write_text(_csv(outcome.table), encoding="utf-8")
        (part / "history.csv").write_text(_csv(history), encoding="utf-8")
        (part / "population.csv").write_text(_csv(population), encoding="utf-8")
        for name, png in outcome.pngs.items():
            (part / name).write_bytes(png)
        tmp[metrics_path.name].write_text(json_text(outcome.metrics), encoding="utf-8")
        tmp[gaits_path.name].write_text(json_text(outcome.gait_doc), encoding="utf-8")
    return folder, gaits_path, metrics_path


def _print_summary(m: dict, gaits_path, metrics_path, folder) -> None:
    """Print the best gait's score and objectives, the cost, how the best were checked, and what was written."""
    from workbench.console import info

    check = (f"re-simulated objectives within {m['resim_max_rel_diff']:.1e}" if m.get("resim_max_rel_diff") is not None
             else f"best {m['verified_direct']} re-swum with the direct rollout in {m['verify_seconds']:.1f} s "
                  f"(tabulated S within {m['verify_max_rel_diff_score']:.2%})")
    info(f"best S {m['best_score']:.4f} (f1 {m['best_f1']:.4g}, f2 {m['best_f2']:.4g}, f3 {m['best_f3']:.4g}); "
         f"{m['evaluations']} evaluations in {m['seconds']:.1f} s; {check}")
    info(f"wrote {gaits_path}, {metrics_path} and {folder}/")


def _log_to_mlflow(args, cfg, outcome, workers, folder, files, source, model, robot) -> None:
    """Log the outcome to MLflow; a failure is a printed warning (the results are already on disk)."""
    from workbench.console import info
    from workbench.gait.tracking import log_outcome

    try:
        settings = cfg.record() | {"task": args.task, "model": args.model, "workers_used": workers}
        run_id = log_outcome(outcome, settings, folder, files, model_spec=args.model, model_source=source,
                             tracking_uri=args.tracking_uri or cfg.tracking.tracking_uri,
                             experiment=cfg.tracking.experiment,
                             campaigns=_campaigns(model, robot.drag_source))
        info(f"MLflow run {run_id} (experiment '{cfg.tracking.experiment}')")
    except Exception as exc:  # noqa: BLE001 - the results are on disk; tracking is the side channel
        info(f"warning: MLflow logging failed ({type(exc).__name__}: {str(exc).splitlines()[0][:160]})")


def _label(label: str | None, spec: str) -> str:
    """The results' name: ``--label`` (checked: file-name safe) or one derived from the model spec."""
    import re

    from workbench.errors import SettingError
    from workbench.gait.export import model_label

    if label is None:
        return model_label(spec)
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}", label):
        raise SettingError(f"{label!r} is not a file-name-safe name", where="--label",
                           hint="letters, digits, '-' and '_', e.g. lstm16")
    return label


def _campaigns(model, drag_source: str) -> list[str]:
    """The campaigns behind a run: the leg model's training data and the towing campaign of the drag fit.

    ``drag_source`` is the robot's (the drag.json it loaded, from --drag or robot.yaml, else its own laws).
    """
    import json
    from pathlib import Path

    ids = list(model.describe().get("campaigns") or [])
    drag_json = drag_source if drag_source.endswith(".json") else None
    if drag_json:
        try:
            source = json.loads(Path(drag_json).read_text(encoding="utf-8")).get("source")
        except (OSError, ValueError):
            source = None
        ids.append(Path(source).stem if source else Path(drag_json).parent.name)
    return ids


def _ours(path) -> bool:
    """A gait or metrics file written before set records existed: a JSON object naming its task."""
    import json

    try:
        return '"task"' in path.read_text(encoding="utf-8")[:4096] and isinstance(json.loads(path.read_text()), dict)
    except (OSError, ValueError):
        return False


def _json(obj) -> str:
    import json

    return json.dumps(obj, indent=2) + "\n"
