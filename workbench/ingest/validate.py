"""``workbench campaign validate``: every contract violation of a campaign, not just the first.

The manifest is checked as a whole (:func:`check_manifest`); then each file of each run is read
and checked on its own, so a run with a bad load-cell file *and* a bad motion file shows both;
runs whose files are all readable are then processed in full (clock alignment, overlap), which
catches missing trigger edges and the like. Saturation is reported as a warning.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from workbench.contract.campaign import Campaign, RunSpec, check_manifest
from workbench.errors import WorkbenchError
from workbench.ingest.campaign import map_runs
from workbench.ingest.params import IngestSettings
from workbench.ingest.readers import ReadSpec, make_reader
from workbench.ingest.run import process_run
from workbench.ingest.streams import check_stream


@dataclass
class Validation:
    """Result of validating a campaign folder."""

    campaign: Campaign | None
    errors: list[WorkbenchError] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    runs_checked: int = 0

    @property
    def ok(self) -> bool:
        """No violation found."""
        return not self.errors

    @property
    def bad_runs(self) -> list[str]:
        """Ids of runs with at least one violation, in manifest order."""
        seen = []
        for e in self.errors:
            if e.run and e.run not in seen:
                seen.append(e.run)
        return seen


def validate_run(campaign: Campaign, run: RunSpec, params: IngestSettings,
                 manifest_ok: bool = True) -> tuple[list[WorkbenchError], dict | None]:
    """Every violation in one run's files, and its quality record when it ingests cleanly.

    The run is processed in full first (one read); only when that fails is each file checked on
    its own, so that faults in several files of the run are all reported.
    """
    if manifest_ok:
        try:
            return [], process_run(campaign, run, params).quality
        except WorkbenchError as exc:
            first = exc
    else:
        first = None
    spec = ReadSpec.for_run(campaign, run.id)
    errors: list[WorkbenchError] = []
    files = [("mcap", run.mcap)] if run.mcap else [("loadcell", run.loadcell), (spec.controller_role,
                                                                              getattr(run, spec.controller_role))]
    for role, path in files:
        if path is None:
            continue  # the manifest check has reported it
        try:
            for s in make_reader(path, role, spec).read().values():
                check_stream(s, params, run.id, campaign.loadcell.full_scale)
        except WorkbenchError as exc:
            errors.append(exc)
    if not errors and first is not None:
        errors.append(first)  # the files are fine one by one: a fault between them (clocks, overlap)
    return errors, None


def validate_campaign(campaign_dir: str | Path, params: IngestSettings | None = None,
                      progress: Callable[[int], None] | None = None) -> Validation:
    """Check the manifest and every run's files; collect all violations and saturation warnings."""
    params = params or IngestSettings()
    camp, manifest_errors = check_manifest(campaign_dir, params.limits)
    result = Validation(campaign=camp, errors=list(manifest_errors))
    if camp is None or any(e.run is None and "schema" in (e.where or "") for e in manifest_errors):
        return result
    bad_in_manifest = {e.run for e in manifest_errors if e.run}
    good = [r for r in camp.runs if r.id not in bad_in_manifest]
    checked = dict(zip([r.id for r in good], map_runs(camp, good, params, task=validate_run, progress=progress),
                       strict=True))
    for run in camp.runs:
        result.runs_checked += 1
        errors, quality = checked.get(run.id) or validate_run(camp, run, params, manifest_ok=False)
        result.errors.extend(errors)
        if quality and quality["saturated"]:
            chans = ", ".join(f"{c} ({n} samples)" for c, n in quality["saturated_samples"].items())
            result.warnings.append(f"run {run.id}: readings at full scale in {chans}")
    return result
