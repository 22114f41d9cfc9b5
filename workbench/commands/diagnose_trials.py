"""``workbench diagnose --trials``: the trajectory level (docs/diagnose-trajectory.md).

The scored pool trials are swum again in the simulator with each leg model, their RMS position
and heading errors compared side by side (``trajectory_errors.json``, ``.png``) and a trajectory
diagnosis run on each (``trajectory_diagnosis.json``: a water current, a yaw drift). The files the
trials come from are read by :mod:`workbench.commands.diagnose_trajectory`.
"""

from __future__ import annotations


def _model_label(spec: str, model) -> str:
    """A readable name for a leg model spec: EF, augmented EF, FED-LSTM, or the spec itself."""
    from workbench.diagnose.augmented import AugmentedLegModel

    if isinstance(model, AugmentedLegModel):
        base = str(model.base_spec)
        return "augmented " + ("EF" if base == "ef" else "FED-LSTM" if "lstm" in base.lower() else base)
    name = str(getattr(model, "name", spec))
    if spec == "ef" or name.lower() in ("ef", "empirical formula"):
        return "EF"
    if "lstm" in spec.lower() or "lstm" in name.lower():
        return "FED-LSTM"
    return spec


def run_trajectories(args, t0: float) -> int:
    """Trajectory level: swim the tracked trials with each model, fit trajectory effects, write the errors."""
    import time
    from pathlib import Path

    from workbench.commands.diagnose_trajectory import read_track_gaits, read_tracks
    from workbench.commands.simulate import robot_simulation_settings
    from workbench.console import info
    from workbench.diagnose.trajectory import TrajectorySettings, diagnose_trajectories, reference_tracks
    from workbench.hydro.robot import RobotSettings, load_robot
    from workbench.params import load_settings

    settings = load_settings(TrajectorySettings, args.params, "diagnose.trajectory", default="pipelines/diagnose.yaml",
                             required=False)
    robot, sim_kw = RobotSettings(), {}
    if Path(args.robot).is_file():
        robot = load_robot(args.robot)
        sim_kw = robot_simulation_settings(args.robot)
    tracks = read_tracks(args.trials, wall_margin_m=settings.wall_margin_m)
    gaits = read_track_gaits(args.gaits, tracks)  # each trial's gait, before any model is loaded
    cut = [tr.trial_id for tr in tracks if tr.cut_at_wall_s is not None]
    info(f"trajectory level on {args.trials}: {len(tracks)} trials" + (f" ({len(cut)} cut where the robot reached "
                                                                        f"the wall: {', '.join(cut)})" if cut else ""))
    specs = list(args.models or [args.model])
    models, runs, diagnoses = _swim_models(specs, tracks, gaits, robot, settings, sim_kw)
    ordered = _in_given_order(specs, models)
    ref_doc = None
    if args.reference:
        ref = read_tracks(args.reference, wall_margin_m=settings.wall_margin_m)
        d = diagnose_trajectories(tracks, reference_tracks(tracks, ref), "reference", settings,
                                  base=str(args.reference))
        diagnoses["reference"] = d
        ref_doc = d.to_json()
    main_label = "reference" if args.reference else next(iter(ordered))
    doc = {"schema": "workbench/trajectory-errors@1", "trials": str(args.trials), "gaits": str(args.gaits),
           "reference": str(args.reference) if args.reference else None,
           "wall_margin_m": settings.wall_margin_m, "cut_at_wall": cut, "models": ordered,
           "runtime_s": round(time.perf_counter() - t0, 1)}
    _write_trajectory_outputs(args, doc, diagnoses.get(main_label), ref_doc, tracks, runs, ordered)
    _print_trajectory_effects(diagnoses)
    if args.metrics:
        _write_trajectory_metrics(Path(args.metrics), ordered)
    if not args.no_mlflow:
        from workbench.diagnose.tracking import log_trajectory_diagnosis

        log_trajectory_diagnosis(doc, diagnoses, Path(args.out), settings, args.tracking_uri)
    info(f"wrote {args.out}/trajectory_errors.json, trajectory_diagnosis.json ({time.perf_counter() - t0:.1f} s)")
    return 0


def _swim_models(specs: list[str], tracks, gaits, robot, settings, sim_kw: dict
                 ) -> tuple[dict[str, dict], dict[str, list], dict[str, object]]:
    """Swim the tracked trials with each model (the EF first: its swims warm-start the others' fixed points).

    Returns, per model label, its errors (with effects, or ``diagnosis_error`` when the trajectory
    diagnosis failed on the data), its swims, and its trajectory diagnosis.
    """
    order = sorted(range(len(specs)), key=lambda k: specs[k] != "ef")
    models: dict[str, dict] = {}
    runs: dict[str, list] = {}
    diagnoses: dict[str, object] = {}
    warm = None
    for k in order:
        label, err, sims, d = _swim_model(specs[k], tracks, gaits, robot, settings, sim_kw, warm)
        if specs[k] == "ef":
            warm = sims
        if d is not None:
            diagnoses[label] = d
        models[label] = err
        runs[label] = sims
    return models, runs, diagnoses


def _swim_model(spec: str, tracks, gaits, robot, settings, sim_kw: dict, warm):
    """One model's swims of the tracked trials, their errors and trajectory diagnosis (None if it failed)."""
    import time

    from workbench.commands.diagnose_trajectory import tabulator
    from workbench.console import info
    from workbench.diagnose.augmented import AugmentedLegModel
    from workbench.diagnose.trajectory import diagnose_trajectories, simulate_tracks, trajectory_errors
    from workbench.errors import DataError
    from workbench.hydro.legmodel import load_leg_model

    model = load_leg_model(spec)
    label = _model_label(spec, model)
    if isinstance(model, AugmentedLegModel):
        model = model.physical()     # a swimming robot meets no tunnel blockage and no load-cell drift
    ts = time.perf_counter()
    sims = simulate_tracks(tracks, gaits, model, robot, settings, sim_kw, warm=warm, tabulate=tabulator)
    sim_s = time.perf_counter() - ts
    err = trajectory_errors(tracks, sims)
    err.update({"spec": spec, "sim_seconds": round(sim_s, 1)})
    for e in err["excluded"]:
        info(f"  {label}: {e['trial_id']} left out: {e['reason']}")
    d = None
    try:
        d = diagnose_trajectories(tracks, sims, label, settings)
        err["effects"], err["unexplained"] = d.effects, d.unexplained
        err["tests"] = d.tests
    except DataError as exc:
        err["effects"], err["unexplained"] = [], []
        err["diagnosis_error"] = str(exc)
    info(f"  {label}: RMS position {err['rms_position_m']:.3f} m, heading {err['rms_heading_deg']:.1f} deg "
         f"({err['n_trials']} converged swims, {sim_s:.0f} s)")
    return label, err, sims, d


def _in_given_order(specs: list[str], models: dict[str, dict]) -> dict[str, dict]:
    """The models' errors in the order their specs were given on the command line."""
    ordered = {}
    for spec in specs:
        for lab, m in models.items():
            if m["spec"] == spec:
                ordered[lab] = m
    return ordered


def _write_trajectory_outputs(args, doc: dict, main, ref_doc: dict | None, tracks, runs: dict, ordered: dict) -> None:
    """trajectory_errors.json, the main and reference diagnoses and the errors figure, into OUT atomically."""
    from pathlib import Path

    from workbench.atomic import atomic_dir, write_json
    from workbench.commands.diagnose import _readable
    from workbench.diagnose.trajectory import fig_errors

    png = None if args.no_figures else fig_errors(tracks, runs, ordered)
    with atomic_dir(Path(args.out)) as tmp:
        write_json(tmp / "trajectory_errors.json", doc)
        if main is not None:
            dj = main.to_json()
            dj["source"] = str(args.trials)
            write_json(tmp / "trajectory_diagnosis.json", dj)
        if ref_doc is not None:
            write_json(tmp / "trajectory_diagnosis_reference.json", ref_doc)
        if png is not None:
            (tmp / "trajectory_errors.png").write_bytes(png)
        _readable(tmp)


def _print_trajectory_effects(diagnoses: dict) -> None:
    """One line per claimed effect and per unexplained residual of each trajectory diagnosis."""
    from workbench.console import info

    for label, d in diagnoses.items():
        for e in d.effects:
            info(f"  {label}: effect {e['name']}: " + ", ".join(f"{k}={v:.4g}" for k, v in e["params"].items()))
        for u in d.unexplained:
            info(f"  {label}: unexplained {u['kind']}" + (f" ({u['rate_dps']:+.2f} deg/s)" if "rate_dps" in u else ""))


def _write_trajectory_metrics(path, ordered: dict) -> None:
    """The DVC metrics file: each model's trajectory errors."""
    from workbench.atomic import write_json

    flat = {label: {k: m.get(k) for k in ("rms_position_m", "rms_heading_deg", "mean_final_position_m",
                                           "n_trials")} for label, m in ordered.items()}
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json(path, {"trajectory_error": flat})
