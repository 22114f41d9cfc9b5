"""``workbench fit-drag``: body drag polynomials from a towing-tank campaign (drag.json, plot, report)."""

from __future__ import annotations

from workbench.commands._help import add_verb


def register(sub) -> None:
    """Add the ``fit-drag`` verb."""
    p = add_verb(
        sub, "fit-drag", help="fit forward and lateral body drag from a towing-tank campaign",
        description="Ingest a towing-tank campaign (or read its processed Parquet file), find each "
        "run's steady-speed stretch from the carriage log, average the force along the towing "
        "direction, and fit F = c2 v^2 + c1 v + c0 per heading by weighted least squares. Writes "
        "OUT/drag.json (data contract section 4, with standard errors, R^2 and flags), "
        "OUT/drag.png (run means, fit, confidence band) and OUT/drag.md (a short report that "
        "flags physically doubtful fits, e.g. drag at rest). Settings: pipelines/drag.yaml.",
        examples="""\
  workbench fit-drag datasets/raw/demo-towing --out datasets/drag/demo-towing
  workbench fit-drag datasets/processed/tank-2025-05.parquet --out datasets/drag/tank-2025-05
  workbench fit-drag datasets/raw/tank-2025-05 --out /tmp/drag --skip-bad-runs
  workbench virtual-lab towing /tmp/tow && workbench fit-drag /tmp/tow --out /tmp/tow-drag
""")
    p.add_argument("campaign", metavar="CAMPAIGN", help="towing-tank campaign folder, or its processed .parquet")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder: created, or replaced whole when it holds an earlier fit-drag output (refused otherwise)")
    p.add_argument("--params", default="pipelines/drag.yaml", metavar="YAML",
                   help="parameter file with a 'fit' section (default: pipelines/drag.yaml; "
                   "built-in defaults when absent)")
    p.add_argument("--ingest-params", default="pipelines/ingest.yaml", metavar="YAML",
                   help="ingest settings for a campaign folder (section 'ingest'; default: pipelines/ingest.yaml, "
                   "built-in defaults when absent)")
    p.add_argument("--skip-bad-runs", action="store_true",
                   help="ingest the good runs of a campaign with bad ones instead of refusing it")
    p.set_defaults(func=run)


def _load_fit_params(path: str):
    from workbench.hydro.drag import DragFitSettings
    from workbench.params import load_settings

    return load_settings(DragFitSettings, path, "fit", default="pipelines/drag.yaml")


def _load_ingest_params(path: str):
    from workbench.ingest.params import IngestSettings
    from workbench.params import load_settings

    return load_settings(IngestSettings, path, "ingest", default="pipelines/ingest.yaml")


def _read(source, skip_bad_runs: bool, ingest_params):
    """The processed frame and a run -> heading map (None for a Parquet file: its heading column rules)."""
    from pathlib import Path

    import polars as pl

    from workbench.contract.campaign import load_campaign
    from workbench.errors import ContractError, DataError

    src = Path(source)
    if src.is_file():
        if src.suffix != ".parquet":
            raise ContractError("expected a campaign folder or a processed .parquet file", path=src)
        try:
            return pl.read_parquet(src), None
        except (OSError, pl.exceptions.ComputeError) as exc:
            raise DataError(f"cannot read Parquet: {exc}", path=src) from None
    campaign = load_campaign(src)
    if campaign.facility != "towing_tank":
        raise ContractError(f"fit-drag needs a towing-tank campaign, this one is {campaign.facility!r}",
                            path=campaign.manifest)
    from workbench.ingest import ingest_campaign

    result = ingest_campaign(src, params=ingest_params, skip_bad_runs=skip_bad_runs)
    return result.frame, {r.id: r.heading for r in campaign.runs}


def run(args) -> int:
    """Fit, then write drag.json, drag.png and drag.md (all computed before anything is written)."""
    from pathlib import Path

    from workbench.atomic import atomic_dir, check_replaceable, write_bytes, write_json, write_text
    from workbench.console import info
    from workbench.errors import WorkbenchError
    from workbench.hydro.drag import fit_drag
    from workbench.hydro.drag_report import drag_figure_png, drag_report_md

    check_replaceable(args.out, "fit-drag")  # before the work, not after it
    params = _load_fit_params(args.params)
    frame, headings = _read(args.campaign, args.skip_bad_runs, _load_ingest_params(args.ingest_params))
    try:
        fit = fit_drag(frame, headings=headings, params=params)
    except WorkbenchError as exc:
        raise type(exc)(exc.fault, path=args.campaign, run=exc.run, where=exc.where, hint=exc.hint) from None
    name = Path(args.campaign).name
    doc = fit.to_json()
    doc["source"] = str(args.campaign)
    png = drag_figure_png(fit, title=f"body drag: {name}")
    report = drag_report_md(fit, str(args.campaign))
    out = Path(args.out)
    # one set: the three files are swapped in together (a kill leaves the old set or the new one)
    with atomic_dir(out, verb="fit-drag") as tmp:
        write_json(tmp / "drag.json", doc)
        write_bytes(tmp / "drag.png", png)
        write_text(tmp / "drag.md", report)
    for h in fit.headings():
        c2, c1, c0 = h.coefficients
        info(f"{h.heading:8s} F = {c2:.3f} v^2 {c1:+.3f} v {c0:+.3f}  R^2 {h.r2:.4f}  "
             f"({len(h.points)} runs, {len(h.flags)} flag(s))")
        for flag in h.flags:
            info(f"  flag: {flag}")
    for run_id, why in fit.skipped:
        info(f"  skipped run {run_id}: {why}")
    info(f"wrote {out / 'drag.json'}, drag.png, drag.md")
    return 0
