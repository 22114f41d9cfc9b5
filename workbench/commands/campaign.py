"""``workbench campaign validate|add|list``: check a campaign folder, register it for DVC, list them."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from workbench.commands._help import add_verb


def register(sub) -> None:
    """Add the ``campaign`` verb with its three actions."""
    p = add_verb(
        sub, "campaign", help="validate, register (DVC) and list tunnel / towing-tank campaigns",
        description="Work with raw campaign folders (data contract section 1). 'validate' lists every contract "
        "violation (manifest fields, file columns, lines, trigger edges) and every value outside the rig's "
        "plausible ranges (speeds, frequencies, angles, cycles, infinite or beyond-full-scale cells; the bounds and "
        "how to raise them with ingest.limits in pipelines/ingest.yaml: docs/campaigns.md), and exits non-zero "
        "if there is any. "
        "'add' validates, registers the campaign in pipelines/campaigns.yaml so `dvc repro` ingests it, and "
        "tracks its raw folder with `dvc add` (folders a pipeline stage produces are already tracked). "
        "'list' shows the registered campaigns. Walk-through: docs/campaigns.md.",
        examples="""\
  workbench campaign validate datasets/raw/tunnel-2025-03
  workbench campaign add datasets/raw/tunnel-2025-03     # then: git add ...; dvc repro
  workbench campaign list
""")
    actions = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    v = actions.add_parser(
        "validate", help="list every contract violation of a campaign folder",
        description="Check a campaign folder against the data contract (section 1) and the rig's plausible "
        "ranges; print every fault with its file, run and line; exit 2 if there is any. A planned campaign "
        "(plan-campaign's manifest, no files yet) is reported as files pending. Nothing is written.",
        epilog="example:\n  workbench campaign validate datasets/raw/tunnel-2025-03",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    v.add_argument("campaign", type=Path, help="the campaign folder (holds campaign.toml)")
    v.set_defaults(func=run_validate)
    a = actions.add_parser(
        "add", help="validate, register in pipelines/campaigns.yaml, track with DVC",
        description="Validate the campaign, register it in pipelines/campaigns.yaml (so `dvc repro` ingests it "
        "and every stage that depends on it runs again) and track its raw folder with `dvc add`. The raw "
        "folder itself is never modified.",
        epilog="example:\n  workbench campaign add datasets/raw/tunnel-2025-03\n  git add pipelines/campaigns.yaml "
        "datasets/raw/tunnel-2025-03.dvc && dvc repro",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    a.add_argument("campaign", type=Path, help="the campaign folder (under datasets/raw/)")
    a.add_argument("--no-dvc", action="store_true", help="register only; do not run `dvc add`")
    a.set_defaults(func=run_add)
    ls = actions.add_parser(
        "list", help="registered campaigns with facility, runs and status",
        description="One line per campaign registered in pipelines/campaigns.yaml: facility, number of runs, "
        "whether DVC tracks it and whether it is processed.")
    ls.set_defaults(func=run_list)


def _validate(folder: Path):
    from workbench.commands.ingest import load_ingest_params
    from workbench.console import info, progress
    from workbench.contract.campaign import check_manifest
    from workbench.ingest.validate import validate_campaign

    params = load_ingest_params(None)
    camp, _ = check_manifest(folder)
    with progress(f"validate {folder.name}", total=len(camp.runs) if camp else 0, unit=" runs") as bar:
        result = validate_campaign(folder, params, progress=bar.advance)
    for e in result.errors:
        print(f"error: {e.format()}", file=sys.stderr)
    for w in result.warnings:
        print(f"warning: {w}", file=sys.stderr)
    if result.errors:
        info(f"{folder}: {len(result.errors)} violation(s)"
             + (f" in {len(result.bad_runs)} run(s): {', '.join(result.bad_runs)}" if result.bad_runs else ""))
        pending = {getattr(e, "run", None) for e in result.errors if "file (or 'mcap')" in getattr(e, "fault", "")}
        if camp is not None and camp.runs and pending >= {r.id for r in camp.runs}:
            info("no run names its files: a planned campaign (workbench plan-campaign), files pending. Measure the "
                 "runs (the rig, or `workbench virtual-lab tunnel DIR --plan campaign.toml`), add each run's file "
                 "entries, then validate again")
    else:
        camp = result.campaign
        info(f"{folder}: valid ({camp.facility}, {len(camp.runs)} runs checked)")
    return result


def run_validate(args) -> int:
    """Print every violation; exit status 2 if there is any."""
    return 0 if _validate(args.campaign).ok else 2


def run_add(args) -> int:
    """Validate, register, track."""
    from workbench.console import info
    from workbench.errors import ContractError
    from workbench.ingest import registry
    from workbench.project import datasets_dir, project_root

    result = _validate(args.campaign)
    if not result.ok:
        info("not added: fix the violations above and run `workbench campaign add` again")
        return 2
    camp = result.campaign
    root = project_root()
    raw = (datasets_dir(root) / "raw").resolve()
    folder = args.campaign.resolve()
    if folder.parent != raw:
        raise ContractError(f"campaign folder must sit in {raw}", path=args.campaign,
                            hint=f"copy it to datasets/raw/{camp.id} and add that")
    track = registry.tracking(root, folder)  # before registering: a .dvc file it refuses changes nothing
    before = registry.load_registry(root)
    added = registry.register(root, camp)
    info(f"registered {camp.id} in {registry.REGISTRY}" if added
         else f"{camp.id} was already registered in {registry.REGISTRY}")
    if track.kind == "stage":
        info(f"not running dvc add: {folder.name} is the {track.detail} (DVC already tracks it)")
    elif track.kind == "added":
        info(f"already tracked by DVC ({track.detail}); run `dvc add` yourself after changing raw files")
    elif args.no_dvc:
        info("not tracked by DVC (--no-dvc)")
    else:
        if track.detail:
            info(f"running dvc add again: {track.detail}")
        try:
            registry.dvc_add(root, folder)
        except Exception:
            if added:
                registry.save_registry(root, before)
            raise
        rel = folder.relative_to(root.resolve())
        info(f"tracked with DVC: {rel}.dvc; commit it: git add {rel}.dvc {rel.parent}/.gitignore "
             f"{registry.REGISTRY}")
    info("next: dvc repro (ingests every registered campaign)")
    return 0


def run_list(args) -> int:
    """Table of registered campaigns."""
    from rich.console import Console
    from rich.table import Table

    from workbench.contract.campaign import check_manifest
    from workbench.ingest import registry
    from workbench.project import datasets_dir, project_root

    root = project_root()
    reg = registry.load_registry(root)
    table = Table(title=f"campaigns registered in {registry.REGISTRY}", title_justify="left")
    for col in ("campaign", "facility", "runs", "status", "DVC", "processed"):
        table.add_column(col)
    for key, ids in reg.items():
        for cid in ids:
            folder = datasets_dir(root) / "raw" / cid
            processed = datasets_dir(root) / "processed" / f"{cid}.parquet"
            if not folder.is_dir():
                table.add_row(cid, key, "", "[yellow]folder missing (dvc pull / dvc repro)[/yellow]", "",
                              "yes" if processed.is_file() else "no")
                continue
            camp, errors = check_manifest(folder)
            status = "ok" if not errors else f"[red]{len(errors)} manifest violation(s)[/red]"
            track = registry.tracking(root, folder)
            table.add_row(cid, camp.facility if camp else key, str(len(camp.runs)) if camp else "?", status,
                          {"stage": "stage output", "added": "dvc add", "untracked": "[yellow]untracked[/yellow]"}
                          [track.kind], "yes" if processed.is_file() else "no")
    Console(file=sys.stdout, width=None if sys.stdout.isatty() else 120).print(table)
    return 0
