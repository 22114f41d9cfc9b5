"""A whole campaign: every run processed (on two threads when it pays), bad runs collected.

By default one bad run refuses the campaign, listing every bad run; with ``skip_bad_runs`` the
rest is ingested and what was left out is recorded (file metadata and quality report).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import polars as pl

from workbench.contract.campaign import Campaign, check_manifest
from workbench.contract.limits import Limits
from workbench.errors import CampaignRefused, ContractError, WorkbenchError
from workbench.ingest.params import IngestSettings
from workbench.ingest.provenance import campaign_hashes
from workbench.ingest.run import RunOutput, angle_source, assemble, process_run


@dataclass
class IngestResult:
    """What ingest made of a campaign: rows (contract section 3), quality report, skipped runs."""

    frame: pl.DataFrame
    quality: dict[str, Any]
    campaign: Campaign
    skipped: list[WorkbenchError] = field(default_factory=list)
    params: IngestSettings = field(default_factory=IngestSettings)
    #: sha256 of campaign.toml and every raw file the runs name (relative paths)
    hashes: dict[str, str] = field(default_factory=dict)
    skip_bad_runs: bool = False


def as_params(params: IngestSettings | Mapping[str, Any] | None) -> IngestSettings:
    """Accept an :class:`IngestSettings`, a parameter-file section, or None (defaults)."""
    if isinstance(params, IngestSettings):
        return params
    return IngestSettings.from_mapping(params)


def load_manifest(campaign_dir: str | Path, limits: Limits | None = None
                  ) -> tuple[Campaign, dict[str, list[ContractError]]]:
    """Parse campaign.toml; raise on campaign-level violations, return run-level ones by run id.

    Values outside ``limits`` (the rig's ranges; default :class:`Limits`) are violations.
    """
    camp, errors = check_manifest(campaign_dir, limits or Limits())
    campaign_level = [e for e in errors if e.run is None]
    if camp is None or campaign_level:
        raise (campaign_level or errors)[0]
    by_run: dict[str, list[ContractError]] = {}
    for e in errors:
        by_run.setdefault(e.run, []).append(e)
    return camp, by_run


#: campaigns with less raw data are processed on one thread (a second one gains little there)
PARALLEL_MIN_BYTES = 64 * 2 ** 20


def _ingest_run(campaign: Campaign, run, params: IngestSettings) -> RunOutput | WorkbenchError:
    try:
        return process_run(campaign, run, params)
    except WorkbenchError as exc:
        return exc


def _workers(params: IngestSettings, runs) -> int:
    if params.workers:
        return min(params.workers, max(1, len(runs)))
    if len(runs) < 4:
        return 1
    size = sum(p.stat().st_size for r in runs for p in r.files() if p.is_file())
    return 1 if size < PARALLEL_MIN_BYTES else max(1, min(2, os.cpu_count() or 1))


def map_runs(campaign: Campaign, runs, params: IngestSettings, task: Callable | None = None,
             progress: Callable[[int], None] | None = None) -> list:
    """Apply ``task(campaign, run, params)`` (default: ingest the run) to each run, results in run order.

    Runs are independent; with ``workers`` > 1 they are spread over threads. Threads, not
    processes: the heavy parts (polars' CSV parser, scipy's filters, numpy) release the GIL, and
    measured on the 2-core machine worker processes lost more to start-up, to shipping results
    back and to single-threaded parsing than they gained.
    """
    task = task or _ingest_run
    n = _workers(params, runs)

    def one(run):
        return task(campaign, run, params)

    if n <= 1:
        results = map(one, runs)
        pool = None
    else:
        pool = ThreadPoolExecutor(n, thread_name_prefix="ingest")
        results = pool.map(one, runs)
    try:
        out = []
        for result in results:
            out.append(result)
            if progress:
                progress(1)
        return out
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)


def ingest_campaign(campaign_dir: str | Path, *, params: IngestSettings | Mapping[str, Any] | None = None,
                    skip_bad_runs: bool = False, progress: Callable[[int], None] | None = None) -> IngestResult:
    """Ingest a campaign folder into one processed frame (measured rows, ``interpolated`` false).

    Raises the first campaign-level violation (manifest, schema version, ...); a bad run
    refuses the whole campaign with :class:`CampaignRefused` listing every bad run, unless
    ``skip_bad_runs`` is set. Nothing is written here; see :func:`write_processed`.
    ``progress`` is called with 1 after each run (a progress bar's advance).
    """
    params = as_params(params)
    campaign, manifest_errors = load_manifest(campaign_dir, params.limits)
    bad: list[WorkbenchError] = [errs[0] for errs in manifest_errors.values()]
    runs = [r for r in campaign.runs if r.id not in manifest_errors]
    outputs: list[RunOutput] = []
    for out in map_runs(campaign, runs, params, progress=progress):
        (bad if isinstance(out, WorkbenchError) else outputs).append(out)
    if bad and (not skip_bad_runs or not outputs):
        raise CampaignRefused(campaign.manifest, _in_manifest_order(campaign, bad))
    bad = _in_manifest_order(campaign, bad)
    frame = assemble(outputs, campaign.facility)
    hashes = campaign_hashes(campaign, {k: v for o in outputs for k, v in o.hashes.items()})
    quality = build_quality(campaign, outputs, bad, params)
    return IngestResult(frame=frame, quality=quality, campaign=campaign, skipped=bad, params=params,
                        hashes=hashes, skip_bad_runs=skip_bad_runs)


def _in_manifest_order(campaign: Campaign, errors: list[WorkbenchError]) -> list[WorkbenchError]:
    order = {r.id: i for i, r in enumerate(campaign.runs)}
    return sorted(errors, key=lambda e: order.get(e.run or "", len(order)))


def build_quality(campaign: Campaign, outputs: list[RunOutput], bad: list[WorkbenchError],
                  params: IngestSettings) -> dict[str, Any]:
    """The campaign's quality report: totals and one record per run (ingested or left out)."""
    records = {o.run_id: o.quality for o in outputs}
    for e in bad:
        records[e.run or "?"] = {"run_id": e.run, "status": "skipped", "error": e.format()}
    runs = [records[r.id] for r in campaign.runs if r.id in records]
    ok = [q for q in runs if q["status"] == "ok"]
    return {
        "campaign_id": campaign.id,
        "facility": campaign.facility,
        "angle_source": angle_source(campaign) if campaign.is_tunnel else None,
        "runs_total": len(campaign.runs),
        "runs_ingested": len(ok),
        "runs_skipped": len(runs) - len(ok),
        "ticks": int(sum(q["ticks"] for q in ok)),
        "dropped_frames": int(sum(q["dropped_frames"] for q in ok)),
        "dropped_bytes": int(sum(q["dropped_bytes"] for q in ok)),
        "runs_saturated": [q["run_id"] for q in ok if q["saturated"]],
        "runs_flagged": [q["run_id"] for q in ok if q["flags"]],
        "params": params.recorded(),
        "runs": runs,
    }
