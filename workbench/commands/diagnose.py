"""``workbench diagnose``: find what a leg force model lacks, add it, report the error before and after."""

from __future__ import annotations

from workbench.commands._help import add_verb


def register(sub) -> None:
    """Add the ``diagnose`` verb."""
    p = add_verb(
        sub, "diagnose", help="close the loop: residual -> effect -> augmented model, error before/after",
        description="Diagnose a leg force model on a water-tunnel campaign. The residual (measured minus "
        "predicted) of every channel is examined (spectrum, stroke-locked part, whiteness, cross-correlation "
        "with inputs and the model's own force, dependence on flow speed, angle, phase, time, zero flow and "
        "rest); candidate effects from the documented library (docs/diagnose.md: servo_lag, added_mass_error, "
        "drag_coefficient_error, tunnel_blockage, loadcell_crosstalk, leg_weight_buoyancy, sensor_drift, "
        "structural_resonance, flow_unsteadiness, circulatory_lag, link_drag, lift) are fitted on training "
        "runs and claimed only when they beat the noise on held-out runs. Writes OUT/diagnosis.json (data "
        "contract section 4), OUT/augmented_model.json (load it anywhere as `augmented:OUT`), OUT/report.md "
        "with figures, and logs the diagnosis to MLflow (experiment 'diagnose'). Settings: "
        "pipelines/diagnose.yaml.",
        examples="""\
  workbench diagnose --campaign datasets/raw/demo-tunnel --model ef --out datasets/diagnosis/demo-tunnel-ef
  workbench diagnose --processed datasets/processed/demo-tunnel.parquet --model lstm --out /tmp/diag-lstm
  workbench diagnose --campaign datasets/raw/tunnel-2025-03 --model augmented:datasets/diagnosis/demo-tunnel-ef \\
      --out /tmp/second-pass                       # diagnose an already augmented model again
  workbench diagnose --campaign /tmp/vl --model ef --out /tmp/d --effects servo_lag,sensor_drift --no-mlflow
  workbench diagnose --campaign datasets/raw/tunnel-new-servo --reference datasets/raw/demo-tunnel --model ef \
      --out /tmp/what-changed                      # only what differs from the reference campaign is named
  workbench diagnose --trials datasets/scores/demo-pool --gaits datasets/gaits --model ef --out /tmp/traj
  workbench virtual-lab tunnel /tmp/vl --truth ef --effect servo_lag:tau_s=0.04 && \\
      workbench diagnose --campaign /tmp/vl --model ef --out /tmp/vl-diag   # does it find the planted lag?
""")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--campaign", metavar="DIR", help="water-tunnel campaign folder (ingested on the fly)")
    src.add_argument("--processed", metavar="FILE", help="processed Parquet file of a tunnel campaign")
    src.add_argument("--trials", metavar="SCORES_DIR",
                     help="trajectory level: a score-trials output folder (scores.csv + trajectories/); the trials "
                     "are swum again in the simulator with --gaits and --model")
    p.add_argument("--gaits", default="datasets/gaits", metavar="DIR",
                   help="with --trials: folder of <task>-<model>.json gait files (default: datasets/gaits)")
    p.add_argument("--robot", default="pipelines/robot.yaml", metavar="YAML",
                   help="with --trials: robot constants for the simulator (default: pipelines/robot.yaml)")
    p.add_argument("--model", default="ef", metavar="MODEL",
                   help="leg force model: ef, lstm, models:/NAME@ALIAS, augmented:DIR or a saved augmented "
                   "model's path (default: ef)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (replaced atomically on success)")
    p.add_argument("--params", default="pipelines/diagnose.yaml", metavar="YAML",
                   help="parameter file with a 'diagnose' section (default: pipelines/diagnose.yaml; built-in "
                   "defaults when absent)")
    p.add_argument("--ingest-params", default="pipelines/ingest.yaml", metavar="YAML",
                   help="ingest settings for --campaign (section 'ingest'; built-in defaults when absent)")
    p.add_argument("--reference", metavar="CAMPAIGN_OR_PROCESSED",
                   help="a reference campaign on the same rig (raw folder or processed Parquet): the base model's "
                   "stroke-locked misfit there (per motion parameters and flow speed) is taken out first, so only "
                   "what changed since (a new servo, load cell, mount, pump) is diagnosed")
    p.add_argument("--effects", metavar="LIST", help="comma-separated candidate effects (default: the whole library)")
    p.add_argument("--max-runs", type=int, metavar="N", help="analyse at most N runs (whole parameter sets)")
    p.add_argument("--skip-bad-runs", action="store_true", help="ingest the good runs of a campaign with bad ones")
    p.add_argument("--tracking-uri", metavar="URI", help="MLflow tracking URI (default: the project's store)")
    p.add_argument("--no-mlflow", action="store_true", help="do not log to MLflow")
    p.add_argument("--no-figures", action="store_true", help="write report.md without PNG figures")
    p.set_defaults(func=run)


def _section(path: str, default_path: str, section: str) -> dict | None:
    """A parameter-file section; None when the default file is absent (built-in defaults apply)."""
    from pathlib import Path

    from workbench.project import load_params, project_root

    if path == default_path and not Path(path).is_file() and not (project_root() / path).is_file():
        return None
    doc = load_params(path)
    return (doc or {}).get(section) or {}


def _frame(args, path: str | None = None):
    """The processed frame, the ingest's low-pass (cutoff, order) and a source label.

    ``path``: a campaign folder or processed file instead of ``--campaign``/``--processed``.
    """
    from pathlib import Path

    from workbench.errors import ContractError

    processed = args.processed if path is None else (path if Path(path).is_file() else None)
    folder = args.campaign if path is None else (path if processed is None else None)
    if processed:
        from workbench.ingest import read_processed, read_provenance

        frame = read_processed(processed)
        try:
            params = read_provenance(processed).get("params", {})
        except ContractError:
            params = {}
        return frame, (params.get("lowpass_cutoff_hz"), params.get("lowpass_order")), str(processed)
    from workbench.contract.campaign import load_campaign
    from workbench.ingest import ingest_campaign

    if not Path(folder).is_dir():
        raise ContractError("no such campaign folder or processed file", path=folder)
    campaign = load_campaign(folder)
    if campaign.facility != "water_tunnel":
        raise ContractError(f"diagnose needs a water-tunnel campaign, this one is {campaign.facility!r}",
                            path=campaign.manifest)
    result = ingest_campaign(Path(folder), params=_section(args.ingest_params, "pipelines/ingest.yaml",
                                                                   "ingest"),
                             skip_bad_runs=args.skip_bad_runs)
    rp = result.params
    return result.frame, (rp.lowpass_cutoff_hz, rp.lowpass_order), str(folder)


def _virtual_truth(args, frame) -> dict | None:
    """For a virtual-lab campaign with the rich truth: the library parameters its truth gives (else None).

    The truth is the campaign folder's ``truth.json`` (``--campaign``), or, for ``--processed``, the
    one in ``datasets/raw/<campaign_id>/`` of this project when its campaign id matches. Real
    campaigns have none, and nothing changes for them.
    """
    import json
    from pathlib import Path

    from workbench.diagnose.library import truth_reference
    from workbench.project import project_root

    if args.campaign:
        path = Path(args.campaign) / "truth.json"
    else:
        ids = frame["campaign_id"].unique().to_list() if "campaign_id" in frame.columns else []
        if len(ids) != 1:
            return None
        path = project_root() / "datasets" / "raw" / str(ids[0]) / "truth.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or not isinstance(doc.get("truth"), dict):
        return None
    if not args.campaign and doc.get("campaign_id") != frame["campaign_id"][0]:
        return None
    ref = truth_reference(doc["truth"])
    return {k: v for k, v in ref.items() if k != "notes"} or None


def _readable(folder) -> None:
    """Open the output up to the usual umask permissions (the atomic temp folder is private)."""
    import os

    mask = os.umask(0)
    os.umask(mask)
    for root, _dirs, files in os.walk(folder):
        os.chmod(root, 0o777 & ~mask)
        for f in files:
            os.chmod(os.path.join(root, f), 0o666 & ~mask)


def run(args) -> int:
    """Diagnose, then write diagnosis.json, augmented_model.json and the report into OUT atomically."""
    import dataclasses
    import time
    from pathlib import Path

    from workbench.atomic import atomic_dir, write_json
    from workbench.console import info
    from workbench.diagnose.chain import Lowpass
    from workbench.diagnose.loop import DiagnoseSettings, diagnose
    from workbench.errors import ContractError
    from workbench.hydro.legmodel import load_leg_model

    t0 = time.perf_counter()
    if args.trials:
        return _run_trajectories(args, t0)
    try:
        settings = DiagnoseSettings.from_mapping(_section(args.params, "pipelines/diagnose.yaml", "diagnose"))
    except TypeError as exc:
        raise ContractError(f"bad diagnose parameter: {exc}", path=args.params) from None
    if args.effects:
        settings = dataclasses.replace(settings, library=dataclasses.replace(
            settings.library, effects=tuple(e.strip() for e in args.effects.split(",") if e.strip())))
    if args.max_runs is not None:
        settings = dataclasses.replace(settings, data=dataclasses.replace(settings.data, max_runs=args.max_runs))
    frame, (cutoff, order), source = _frame(args)
    lowpass = None
    if settings.match_lowpass:
        lowpass = Lowpass(float(settings.lowpass_cutoff_hz or cutoff or 6.0), int(settings.lowpass_order or order or 4))
    reference, ref_source = None, "reference"
    if args.reference:
        reference, (ref_cut, _), ref_source = _frame(args, args.reference)
        if lowpass is not None and ref_cut is not None and abs(float(ref_cut) - lowpass.cutoff_hz) > 1e-9:
            info(f"  note: the reference was low-passed at {ref_cut} Hz, this campaign at {lowpass.cutoff_hz} Hz")
    model = load_leg_model(args.model)
    info(f"diagnose {args.model} on {source}" + (f" against reference {ref_source}" if args.reference else ""))
    d = diagnose(frame, model, args.model, settings=settings, lowpass=lowpass, source=source,
                 progress=lambda msg: info(f"  {msg}"), reference=reference, reference_source=ref_source)
    doc = d.to_json()
    doc["source"] = source
    truth = _virtual_truth(args, frame) if args.model == "ef" and not args.reference else None
    if truth:  # a virtual campaign: what its ground truth gives each claimed effect, beside the fit
        for e in doc["effects"]:
            if e["name"] in truth:
                e["virtual_truth"] = truth[e["name"]]
    out = Path(args.out)
    from workbench.diagnose.report import write_report

    with atomic_dir(out) as tmp:
        write_json(tmp / "diagnosis.json", doc)
        d.augmented.save(tmp / "augmented_model.json")
        write_report(d, tmp, figures=not args.no_figures, truth=truth)
        _readable(tmp)
    for e in d.effects:
        params = ", ".join(f"{k}={v:.4g}" for k, v in e.params.items() if isinstance(v, float))
        info(f"  effect {e.name}: {params} (held-out error -{e.heldout_mse_reduction:.0%})")
    for u in d.unexplained:
        f = f" at {u.frequency_hz:.2f} Hz" if u.frequency_hz is not None else ""
        info(f"  unexplained {u.kind}{f} in {', '.join(u.channels)}")
    if not args.no_mlflow:
        from workbench.diagnose.tracking import log_diagnosis

        log_diagnosis(d, out, args.tracking_uri)
    info(f"wrote {out}/diagnosis.json, augmented_model.json, report.md ({time.perf_counter() - t0:.1f} s)")
    return 0


def _run_trajectories(args, t0: float) -> int:
    """Trajectory level: simulate the tracked trials, fit trajectory effects, write trajectory_diagnosis.json."""
    import time
    from pathlib import Path

    from workbench.atomic import atomic_dir, write_json
    from workbench.console import info
    from workbench.diagnose.augmented import AugmentedLegModel
    from workbench.diagnose.report import fig_trajectories
    from workbench.diagnose.trajectory import (
        TrajectorySettings,
        diagnose_trajectories,
        read_tracks,
        simulate_tracks,
    )
    from workbench.hydro.legmodel import load_leg_model
    from workbench.hydro.robot import RobotParams, load_robot

    section = _section(args.params, "pipelines/diagnose.yaml", "diagnose") or {}
    traj = dict(section.get("trajectory") or {})
    if "yaw_bounds_dps" in traj:
        traj["yaw_bounds_dps"] = tuple(traj["yaw_bounds_dps"])
    settings = TrajectorySettings(**traj)
    model = load_leg_model(args.model)
    if isinstance(model, AugmentedLegModel):
        model = model.physical()     # a swimming robot meets no tunnel blockage and no load-cell drift
    robot = load_robot(args.robot) if Path(args.robot).is_file() else RobotParams()
    tracks = read_tracks(args.trials)
    info(f"trajectory diagnosis of {args.model}: {len(tracks)} trials, simulating their gaits")
    sims = simulate_tracks(tracks, args.gaits, model, robot, settings)
    d = diagnose_trajectories(tracks, sims, args.model, settings)
    doc = d.to_json()
    doc["source"] = str(args.trials)
    with atomic_dir(Path(args.out)) as tmp:
        write_json(tmp / "trajectory_diagnosis.json", doc)
        fig_trajectories(tracks, sims, d, tmp / "trajectories.png")
        _readable(tmp)
    for e in d.effects:
        info(f"  effect {e['name']}: {e['params']} (left-out error -{e['cv_error_reduction']:.0%})")
    rms = doc["rms_position_error_m"]
    info(f"  RMS position error {rms['before']:.3f} m -> {rms['after']:.3f} m")
    info(f"wrote {args.out}/trajectory_diagnosis.json ({time.perf_counter() - t0:.1f} s)")
    return 0
