"""``workbench diagnose``: find what a leg force model lacks, add it, report the error before and after."""

from __future__ import annotations

from workbench.commands._help import add_verb
from workbench.commands.diagnose_trials import (  # noqa: F401 - the trajectory level, importable from here as before
    _in_given_order,
    _model_label,
    _print_trajectory_effects,
    _swim_model,
    _swim_models,
    _write_trajectory_metrics,
    _write_trajectory_outputs,
    run_trajectories,
)


def _library_names() -> str:
    """The effect library's names from the package metadata (entry points; no effect module is imported)."""
    from importlib.metadata import entry_points

    # workbench.diagnose.library.ENTRY_POINT_GROUP; not imported here: it loads numpy and scipy (2 s) on every verb
    return ", ".join(sorted(e.name for e in entry_points(group="workbench.effects"))) or "none installed"


def register(sub) -> None:
    """Add the ``diagnose`` verb."""
    p = add_verb(
        sub, "diagnose", help="close the loop: residual -> effect -> augmented model, error before/after",
        description="Diagnose a leg force model on a water-tunnel campaign. The residual (measured minus "
        "predicted) of every channel is examined (spectrum, stroke-locked part, whiteness, cross-correlation "
        "with inputs and the model's own force, dependence on flow speed, angle, phase, time, zero flow and "
        "rest); candidate effects from the effect library (docs/diagnose.md section 2; their names are listed "
        "under --effects) are fitted on training "
        "runs and claimed only when they beat the noise on held-out runs. Writes OUT/diagnosis.json (data "
        "contract section 4), OUT/augmented_model.json (load it anywhere as `augmented:OUT`), OUT/report.md "
        "with figures, and logs the diagnosis to MLflow (experiment 'diagnose'). Settings: "
        "pipelines/diagnose.yaml. Trajectory level (--trials, docs/diagnose-trajectory.md): the scored pool "
        "trials are swum again in the simulator with each leg model (--models), the RMS position and heading "
        "errors are compared side by side (OUT/trajectory_errors.json, .png), and a water current or a yaw drift "
        "is named when the trials show one (OUT/trajectory_diagnosis.json).",
        examples="""\
  workbench diagnose --campaign datasets/raw/demo-tunnel --model ef --out datasets/diagnosis/demo-tunnel-ef
  workbench diagnose --processed datasets/processed/demo-tunnel.parquet --model lstm --out /tmp/diag-lstm
  workbench diagnose --campaign datasets/raw/tunnel-2025-03 --model augmented:datasets/diagnosis/demo-tunnel-ef \\
      --out /tmp/second-pass                       # diagnose an already augmented model again
  workbench diagnose --campaign /tmp/vl --model ef --out /tmp/d --effects servo_lag,sensor_drift --no-mlflow
  workbench diagnose --campaign datasets/raw/tunnel-new-servo --reference datasets/raw/demo-tunnel --model ef \\
      --out /tmp/what-changed                      # only what differs from the reference campaign is named
  workbench diagnose --trials datasets/scores/demo-pool --gaits datasets/gaits --model ef --out /tmp/traj
  workbench diagnose --trials datasets/scores/demo-pool --models ef \\
      datasets/diagnosis/demo-tunnel-ef/augmented_model.json datasets/models/fed-lstm --out /tmp/traj3
                                                   # trajectory error of three leg models side by side
  workbench diagnose --trials /tmp/pool-after --reference datasets/scores/demo-pool --out /tmp/pool-changed
                                                   # current or yaw drift since a reference pool session
  workbench virtual-lab tunnel /tmp/vl --truth ef --effect servo_lag:tau_s=0.04 && \\
      workbench diagnose --campaign /tmp/vl --model ef --out /tmp/vl-diag   # does it find the planted lag?
""")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--campaign", metavar="DIR", help="water-tunnel campaign folder (ingested on the fly)")
    src.add_argument("--processed", metavar="FILE", help="processed Parquet file of a tunnel campaign")
    src.add_argument("--trials", metavar="SCORES_DIR",
                     help="trajectory level: a score-trials output folder (scores.csv + trajectories/); the trials "
                     "are swum again in the simulator with --gaits and --model (or each of --models); "
                     "docs/diagnose-trajectory.md")
    p.add_argument("--gaits", default="datasets/gaits", metavar="DIR",
                   help="with --trials: folder of <task>-<model>.json gait files (default: datasets/gaits)")
    p.add_argument("--robot", default="pipelines/robot.yaml", metavar="YAML",
                   help="with --trials: robot constants for the simulator (default: pipelines/robot.yaml)")
    p.add_argument("--model", default="ef", metavar="MODEL",
                   help="leg force model: ef, lstm, models:/NAME@ALIAS, augmented:DIR or a saved augmented "
                   "model's path (default: ef)")
    p.add_argument("--models", nargs="+", metavar="MODEL",
                   help="with --trials: swim the trials with each of these leg models and compare them (RMS position "
                   "and heading error side by side, trajectory_errors.json); e.g. ef "
                   "datasets/diagnosis/demo-tunnel-ef/augmented_model.json datasets/models/fed-lstm")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (replaced atomically on success)")
    p.add_argument("--params", default="pipelines/diagnose.yaml", metavar="YAML",
                   help="parameter file with a 'diagnose' section (default: pipelines/diagnose.yaml; built-in "
                   "defaults when absent)")
    p.add_argument("--ingest-params", default="pipelines/ingest.yaml", metavar="YAML",
                   help="ingest settings for --campaign (section 'ingest'; built-in defaults when absent)")
    p.add_argument("--reference", metavar="CAMPAIGN_OR_PROCESSED",
                   help="a reference campaign on the same rig (raw folder or processed Parquet): the base model's "
                   "stroke-locked misfit there (per motion parameters and flow speed) is taken out first, so only "
                   "what changed since (a new servo, load cell, mount, pump) is diagnosed. With --trials: a "
                   "reference pool session (score-trials folder, the same gaits swum before): its tracks are the "
                   "base, so a yaw drift can be named (without one it is only reported)")
    p.add_argument("--metrics", metavar="JSON",
                   help="with --trials: also write the models' RMS errors here (flat JSON for `dvc metrics`)")
    p.add_argument("--tunnel-area", type=float, metavar="M2",
                   help="the test section's cross-section (m^2) when the manifest has no [tunnel] test_section_area_m2: "
                   "tunnel_blockage then takes Maskell's prior (docs/diagnose.md)")
    p.add_argument("--effects", metavar="LIST", help=f"comma-separated candidate effects (default: the whole library: {_library_names()})")
    p.add_argument("--max-runs", type=int, metavar="N", help="analyse at most N runs (whole parameter sets)")
    p.add_argument("--skip-bad-runs", action="store_true", help="ingest the good runs of a campaign with bad ones")
    p.add_argument("--tracking-uri", metavar="URI", help="MLflow tracking URI (default: the project's store)")
    p.add_argument("--no-mlflow", action="store_true", help="do not log to MLflow")
    p.add_argument("--no-figures", action="store_true", help="write report.md without PNG figures")
    p.set_defaults(func=run)


def _section(path: str, default_path: str, section: str) -> dict:
    """A parameter-file section (workbench.params.read_section); empty when the default file is absent."""
    from workbench.params import read_section

    return read_section(path, section, default=default_path)[0]


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


def _with_tunnel_area(settings, args):
    """``tunnel_blockage``'s cross-section: the manifest's ``[tunnel]`` table, else ``--tunnel-area``, else the params file."""
    import dataclasses

    from workbench.errors import ParamsError

    area = None
    if args.campaign:
        from workbench.contract.campaign import load_campaign

        area = load_campaign(args.campaign).test_section_area_m2
    if area is None:
        area = args.tunnel_area
    if area is None:
        return settings
    if not area > 0:
        raise ParamsError(f"--tunnel-area must be a positive cross-section in m^2, got {area}")
    opts = dict(settings.library.options or {})
    opts["tunnel_blockage"] = {**(opts.get("tunnel_blockage") or {}), "test_section_area_m2": float(area)}
    return dataclasses.replace(settings, library=dataclasses.replace(settings.library, options=opts))


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


def _write_files(folder, files: dict) -> None:
    """``{relative name: text or bytes}`` into ``folder`` (an atomic temp folder), sub-folders made as needed."""
    from pathlib import Path

    for name, data in files.items():
        path = Path(folder) / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(data, bytes):
            path.write_bytes(data)
        else:
            path.write_text(data, encoding="utf-8")


def run(args) -> int:
    """Diagnose, then write diagnosis.json, augmented_model.json and the report into OUT atomically."""
    import time
    from pathlib import Path

    from workbench.atomic import atomic_dir, check_replaceable, write_json
    from workbench.console import info
    from workbench.diagnose.loop import diagnose
    from workbench.hydro.legmodel import load_leg_model

    check_replaceable(args.out, "diagnose")  # a wrong --out is refused before the work, not after

    t0 = time.perf_counter()
    if args.trials:
        return run_trajectories(args, t0)
    settings = _settings(args)
    frame, (cutoff, order), source = _frame(args)
    settings = _with_tunnel_area(settings, args)
    lowpass = _lowpass(settings, cutoff, order)
    reference, ref_source = _reference(args, lowpass)
    model = load_leg_model(args.model)
    info(f"diagnose {args.model} on {source}" + (f" against reference {ref_source}" if args.reference else ""))
    d = diagnose(frame, model, args.model, settings=settings, lowpass=lowpass, source=source,
                 progress=lambda msg: info(f"  {msg}"), reference=reference, reference_source=ref_source)
    doc = d.to_json()
    doc["source"] = source
    truth = _virtual_truth(args, frame) if args.model == "ef" and not args.reference else None
    if truth:  # a virtual campaign: what its ground truth gives each claimed effect, beside the fit
        _add_truth(doc, truth)
    out = Path(args.out)
    from workbench.diagnose.report import render_report

    report = render_report(d, figures=not args.no_figures, truth=truth)
    with atomic_dir(out) as tmp:  # diagnosis, augmented model, report and figures: one set
        write_json(tmp / "diagnosis.json", doc)
        d.augmented.save(tmp / "augmented_model.json")
        _write_files(tmp, report)
        _readable(tmp)
    _print_claims(d)
    if not args.no_mlflow:
        from workbench.diagnose.tracking import log_diagnosis

        log_diagnosis(d, out, args.tracking_uri)
    info(f"wrote {out}/diagnosis.json, augmented_model.json, report.md ({time.perf_counter() - t0:.1f} s)")
    return 0


def _settings(args):
    """The diagnose settings: the parameter file's ``diagnose`` section, then ``--effects`` and ``--max-runs``."""
    import dataclasses

    from workbench.diagnose.loop import DiagnoseSettings
    from workbench.params import read_section

    settings = DiagnoseSettings.from_mapping(*read_section(args.params, "diagnose", default="pipelines/diagnose.yaml"))
    if args.effects:
        settings = dataclasses.replace(settings, library=dataclasses.replace(
            settings.library, effects=tuple(e.strip() for e in args.effects.split(",") if e.strip())))
    if args.max_runs is not None:
        settings = dataclasses.replace(settings, data=dataclasses.replace(settings.data, max_runs=args.max_runs))
    return settings


def _lowpass(settings, cutoff, order):
    """The ingest's low-pass applied to the model's prediction too (None when ``match_lowpass`` is off)."""
    from workbench.diagnose.chain import Lowpass

    if not settings.match_lowpass:
        return None
    return Lowpass(float(settings.lowpass_cutoff_hz or cutoff or 6.0), int(settings.lowpass_order or order or 4))


def _reference(args, lowpass) -> tuple:
    """The ``--reference`` campaign's frame and source label (None, "reference" without one).

    A reference low-passed at another cutoff than this campaign is noted, not refused.
    """
    from workbench.console import info

    if not args.reference:
        return None, "reference"
    reference, (ref_cut, _), ref_source = _frame(args, args.reference)
    if lowpass is not None and ref_cut is not None and abs(float(ref_cut) - lowpass.cutoff_hz) > 1e-9:
        info(f"  note: the reference was low-passed at {ref_cut} Hz, this campaign at {lowpass.cutoff_hz} Hz")
    return reference, ref_source


def _add_truth(doc: dict, truth: dict) -> None:
    """Each claimed effect's virtual-truth parameters beside its fitted ones in ``doc`` (in place)."""
    for e in doc["effects"]:
        if e["name"] in truth:
            e["virtual_truth"] = truth[e["name"]]


def _print_claims(d) -> None:
    """One line per claimed effect (its parameters and held-out reduction) and per unexplained residual."""
    from workbench.console import info

    for e in d.effects:
        params = ", ".join(f"{k}={v:.4g}" for k, v in e.params.items() if isinstance(v, float))
        info(f"  effect {e.name}: {params} (held-out error {-e.heldout_mse_reduction:+.0%})")
    for u in d.unexplained:
        f = f" at {u.frequency_hz:.2f} Hz" if u.frequency_hz is not None else ""
        info(f"  unexplained {u.kind}{f} in {', '.join(u.channels)}")
    for note in d.not_converged():
        info(f"  note: {note}")
