"""Score every trial of a trials folder: a bad trial is recorded with its error, the others still scored."""

from __future__ import annotations

import os
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

from workbench.contract.trials import TrialsFolder, TrialSpec, load_trials
from workbench.errors import ContractError, WorkbenchError
from workbench.trials.params import ScoringSettings
from workbench.trials.trial import TrialResult, score_trial


@dataclass(frozen=True)
class TrialFailure:
    """A trial that could not be scored, with its one-line error."""

    spec: TrialSpec
    error: str


@dataclass(frozen=True)
class FolderResult:
    """Scored trials (manifest order) and failures of one folder."""

    folder: TrialsFolder
    results: tuple[TrialResult, ...]
    failures: tuple[TrialFailure, ...]
    params: ScoringSettings


def _one(args) -> tuple[str, TrialResult | None, str | None]:
    spec, robot, params, overlay = args
    try:
        return spec.id, score_trial(spec, robot, params, overlay_path=overlay), None
    except WorkbenchError as exc:
        return spec.id, None, exc.format()


def _worker_init() -> None:
    import cv2

    # one process per core already; OpenCV's own thread pool would only oversubscribe
    cv2.setNumThreads(1)


def score_folder(root: str | Path, params: ScoringSettings | None = None, *, overlay_dir: str | Path | None = None,
                 trial_ids: list[str] | None = None, show_progress: bool = True) -> FolderResult:
    """Score the trials of ``root`` (all, or those named); raise only for folder-level faults.

    With ``params.workers`` > 1 the trials run in that many processes. Overlay videos go to
    ``overlay_dir/<trial_id>.mp4`` when a folder is given and ``params.overlay`` is on.
    """
    from workbench.console import progress

    p = params or ScoringSettings()
    folder, per_trial = load_trials(root)
    specs = list(folder.trials)
    if trial_ids:
        known = {s.id for s in specs}
        missing = [t for t in trial_ids if t not in known]
        if missing:
            raise ContractError(f"no trial(s) {', '.join(missing)} in the manifest", path=folder.manifest)
        specs = [s for s in specs if s.id in trial_ids]
    failures: dict[str, str] = {}
    jobs = []
    for s in specs:
        if s.id in per_trial:
            failures[s.id] = per_trial[s.id][0].format()
        else:
            ov = None
            if overlay_dir is not None and p.overlay:
                ov = Path(overlay_dir) / f"{s.id}.mp4"
            jobs.append((s, folder.robot, p, ov))
    results: dict[str, TrialResult] = {}
    workers = max(1, min(int(p.workers), len(jobs), os.cpu_count() or 1))
    bar_ctx = progress("scoring trials", total=len(specs)) if show_progress else nullcontext(_Quiet())
    with bar_ctx as bar:
        for s in specs:
            if s.id in failures:
                bar.advance(1, f"{s.id}: FAILED")
        if workers == 1:
            outcomes = (_one(j) for j in jobs)
            _collect(outcomes, results, failures, bar)
        else:
            from concurrent.futures import as_completed

            from workbench.procs import process_pool  # workers die with this process; Ctrl-C ends them

            with process_pool(workers, initializer=_worker_init) as ex:
                futs = [ex.submit(_one, j) for j in jobs]
                _collect((f.result() for f in as_completed(futs)), results, failures, bar)
    order = [s.id for s in specs]
    return FolderResult(
        folder=folder,
        results=tuple(results[i] for i in order if i in results),
        failures=tuple(TrialFailure(spec=next(s for s in specs if s.id == i), error=failures[i])
                       for i in order if i in failures),
        params=p,
    )


class _Quiet:
    def advance(self, n=1, status=None):
        pass


def _collect(outcomes, results, failures, bar) -> None:
    for tid, res, err in outcomes:
        if res is not None:
            results[tid] = res
            sc = res.score
            extra = (f"mae {sc.mae_x_m:.3f} m" if sc.mae_x_m is not None
                     else f"r {sc.radius_m:.3f} m" if sc.radius_m is not None else "no circle (swam straight)")
            bar.advance(1, f"{tid}: {sc.time_s:.1f} s, {extra}")
        else:
            failures[tid] = err
            bar.advance(1, f"{tid}: FAILED")
