"""``workbench ingest DIR --out FILE``: one campaign folder to one processed Parquet file."""

from __future__ import annotations

from pathlib import Path

from workbench.commands._help import add_verb

PARAMS_FILE = "pipelines/ingest.yaml"


def register(sub) -> None:
    """Add the ``ingest`` verb."""
    p = add_verb(
        sub, "ingest", help="raw campaign folder -> processed Parquet (aligned, filtered, on controller ticks)",
        description="Read every run of a campaign (CSV, .bin serial captures or MCAP), check it against the "
        "data contract, align the load cell's clock to the controller's by pairing trigger edges, low-pass "
        "(zero-phase, 6 Hz by default) and resample the forces onto the controller's ticks, add joint angular "
        "velocities (or carriage speed), and write one Parquet file with provenance metadata plus a quality "
        "report (<name>.quality.json). A campaign with a bad run is refused, listing every bad run, unless "
        "--skip-bad-runs. Values outside the rig's plausible ranges are bad (docs/campaigns.md, 'Plausible "
        "values'; raise a bound with ingest.limits in the parameter file). Unchanged raw files and parameters are "
        "not reprocessed (a stale quality report beside them is rewritten from the Parquet metadata). --out inside "
        "a raw campaign folder is refused: raw folders are never modified (docs/data-outputs.md). Parameters: the "
        f"'ingest' section of {PARAMS_FILE} (see docs/ingest.md).",
        examples="""\
  workbench ingest datasets/raw/demo-tunnel                      # -> datasets/processed/demo-tunnel.parquet
  workbench ingest datasets/raw/tunnel-2025-03 --out /tmp/t.parquet
  workbench ingest datasets/raw/tunnel-2025-03 --skip-bad-runs   # ingest the good runs, record the rest
  workbench ingest datasets/raw/tunnel-2025-03 --force           # reprocess even if up to date
  python -c "import workbench.ingest as i; print(i.read_provenance('datasets/processed/demo-tunnel.parquet'))"
""")
    p.add_argument("campaign", type=Path, help="campaign folder (holds campaign.toml)")
    p.add_argument("--out", type=Path, default=None,
                   help="output file (default: datasets/processed/<campaign_id>.parquet)")
    p.add_argument("--params", type=Path, default=None,
                   help=f"parameter file with an 'ingest' section (default: {PARAMS_FILE} if present)")
    p.add_argument("--skip-bad-runs", action="store_true",
                   help="ingest the good runs and record the bad ones instead of refusing the campaign")
    p.add_argument("--force", action="store_true", help="reprocess even when the output is up to date")
    p.add_argument("--workers", type=int, default=None, help="worker threads over runs (default: automatic, at most 2)")
    p.add_argument("--quiet", action="store_true", help="no quality table on the terminal")
    p.set_defaults(func=run)


def load_ingest_params(path: Path | None, **overrides):
    """The ``ingest`` settings: the --params file, else the project's pipelines/ingest.yaml, else defaults."""
    from workbench.ingest.params import IngestSettings
    from workbench.params import load_settings

    return load_settings(IngestSettings, path, "ingest", default=PARAMS_FILE, overrides=overrides)


def run(args) -> int:
    """Ingest (or say the output is up to date) and show the quality report."""
    from workbench.console import info, progress
    from workbench.contract.campaign import load_campaign
    from workbench.ingest import ingest_to_file, quality_path, read_provenance
    from workbench.ingest.quality import render_quality, summary_line
    from workbench.project import datasets_dir

    params = load_ingest_params(args.params, workers=args.workers)
    camp = load_campaign(args.campaign)
    out = args.out or datasets_dir() / "processed" / f"{camp.id}.parquet"
    if args.quiet:
        result = ingest_to_file(args.campaign, out, params=params, skip_bad_runs=args.skip_bad_runs, force=args.force)
    else:
        with progress(f"ingest {camp.id}", total=len(camp.runs), unit=" runs") as bar:
            result = ingest_to_file(args.campaign, out, params=params, skip_bad_runs=args.skip_bad_runs,
                                    force=args.force, progress=bar.advance)
    if result is None:
        meta = read_provenance(out)  # ingest_to_file has brought quality.json in line with it
        info(f"up to date: {out} already holds these {len(meta['raw_files'])} raw files processed with the same "
             f"parameters; not reprocessed (--force to redo)")
        info(summary_line(meta["quality"]))
        return 0
    if not args.quiet:
        render_quality(result.quality)
    for e in result.skipped:
        info(f"left out: {e.format()}")
    info(f"wrote {out} ({result.frame.height:,} rows) and {quality_path(out)}")
    return 0
