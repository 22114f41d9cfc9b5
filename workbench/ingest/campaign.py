"""A whole campaign: every run processed (in worker processes when it pays), bad runs collected.

By default one bad run refuses the campaign, listing every bad run; with ``skip_bad_runs`` the
rest is ingested and what was left out is recorded (file metadata and quality report).
"""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import polars as pl

from workbench.contract.campaign import Campaign, check_manifest
from workbench.errors import CampaignRefused, ContractError, WorkbenchError
from workbench.ingest.params import IngestParams
from workbench.ingest.provenance import campaign_hashes
from workbench.ingest.run import RunOutput, angle_source, process_run
from workbench.ingest.schema import columns_for

#: campaigns with fewer runs are processed in this process (starting workers costs ~1 s)
PARALLEL_MIN_RUNS = 40


@dataclass
class IngestResult:
    """What ingest made of a campaign: rows (contract section 3), quality report, skipped runs."""

    frame: pl.DataFrame
    quality: dict[str, Any]
    campaign: Campaign
    skipped: list[WorkbenchError] = field(default_factory=list)
    params: IngestParams = field(default_factory=IngestParams)
    #: sha256 of campaign.toml and every raw file the runs name (relative paths)
    hashes: dict[str, str] = field(default_factory=dict)
    skip_bad_runs: bool = False


def as_params(params: IngestParams | Mapping[str, Any] | None) -> IngestParams:
    """Accept an :class:`IngestParams`, a parameter-file section, or None (defaults)."""
    if isinstance(params, IngestParams):
        return params
    return IngestParams.from_mapping(params)


def load_manifest(campaign_dir: str | Path) -> tuple[Campaign, dict[str, list[ContractError]]]:
    """Parse campaign.toml; raise on campaign-level violations, return run-level ones by run id."""
    camp, errors = check_manifest(campaign_dir)
    campaign_level = [e for e in errors if e.run is None]
    if camp is None or campaign_level:
        raise (campaign_level or errors)[0]
    by_run: dict[str, list[ContractError]] = {}
    for e in errors:
        by_run.setdefault(e.run, []).append(e)
    return camp, by_run


def _one(args) -> RunOutput | WorkbenchError:
    campaign, run, params = args
    try:
        return process_run(campaign, run, params)
    except WorkbenchError as exc:
        return exc


def _workers(params: IngestParams, n_runs: int) -> int:
    if params.workers:
        return params.workers
    if n_runs < PARALLEL_MIN_RUNS:
        return 1
    return max(1, min(2, os.cpu_count() or 1))


def _map_runs(campaign: Campaign, runs, params: IngestParams) -> list[RunOutput | WorkbenchError]:
    jobs = [(campaign, r, params) for r in runs]
    n = _workers(params, len(jobs))
    if n <= 1:
        return [_one(j) for j in jobs]
    import multiprocessing as mp

    # polars and scipy start thread pools; with one process per core, one thread each is best
    saved = {k: os.environ.get(k) for k in ("POLARS_MAX_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}
    os.environ.update({k: "1" for k in saved})
    try:
        with ProcessPoolExecutor(n, mp_context=mp.get_context("spawn")) as pool:
            return list(pool.map(_one, jobs, chunksize=max(1, len(jobs) // (8 * n))))
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def ingest_campaign(campaign_dir: str | Path, *, params: IngestParams | Mapping[str, Any] | None = None,
                    skip_bad_runs: bool = False) -> IngestResult:
    """Ingest a campaign folder into one processed frame (measured rows, ``interpolated`` false).

    Raises the first campaign-level violation (manifest, schema version, ...); a bad run
    refuses the whole campaign with :class:`CampaignRefused` listing every bad run, unless
    ``skip_bad_runs`` is set. Nothing is written here; see :func:`write_processed`.
    """
    params = as_params(params)
    campaign, manifest_errors = load_manifest(campaign_dir)
    bad: list[WorkbenchError] = [errs[0] for errs in manifest_errors.values()]
    runs = [r for r in campaign.runs if r.id not in manifest_errors]
    outputs: list[RunOutput] = []
    for out in _map_runs(campaign, runs, params):
        (bad if isinstance(out, WorkbenchError) else outputs).append(out)
    if bad and (not skip_bad_runs or not outputs):
        raise CampaignRefused(campaign.manifest, _in_manifest_order(campaign, bad))
    bad = _in_manifest_order(campaign, bad)
    frame = pl.concat([o.frame for o in outputs], how="vertical") if outputs else pl.DataFrame(
        schema={c: pl.Float64 for c in columns_for(campaign.facility)})
    hashes = campaign_hashes(campaign, {k: v for o in outputs for k, v in o.hashes.items()})
    quality = build_quality(campaign, outputs, bad, params)
    return IngestResult(frame=frame, quality=quality, campaign=campaign, skipped=bad, params=params,
                        hashes=hashes, skip_bad_runs=skip_bad_runs)


def _in_manifest_order(campaign: Campaign, errors: list[WorkbenchError]) -> list[WorkbenchError]:
    order = {r.id: i for i, r in enumerate(campaign.runs)}
    return sorted(errors, key=lambda e: order.get(e.run or "", len(order)))


def build_quality(campaign: Campaign, outputs: list[RunOutput], bad: list[WorkbenchError],
                  params: IngestParams) -> dict[str, Any]:
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
