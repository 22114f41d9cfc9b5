"""Writing a scored folder: scores.csv, summary.json, comparison.md, trajectories, plots, overlays.

The output folder is built beside its target and swapped in only when everything is written,
so a failed run leaves the previous results as they were. Failed trials are not rows of
scores.csv (it holds only scores that exist); summary.json lists them with their errors.
"""

from __future__ import annotations

from pathlib import Path

from workbench.errors import ContractError, DataError
from workbench.trials.compare import compare_models, comparison_markdown, model_statistics, scores_frame
from workbench.trials.folder import FolderResult, score_folder
from workbench.trials.params import ScoringSettings

SUMMARY_SCHEMA = "workbench/trial-scores@1"


def score_rows(result: FolderResult) -> list[dict]:
    """One scores.csv row per scored trial."""
    rows = []
    for r in result.results:
        s = r.score
        rows.append({"trial_id": r.spec.id, "model": r.spec.model, "solution": r.spec.solution, "task": r.spec.task,
                     "time_s": round(s.time_s, 4), "mae_x_m": None if s.mae_x_m is None else round(s.mae_x_m, 5),
                     "radius_m": None if s.radius_m is None else round(s.radius_m, 5), "completed": s.completed})
    return rows


def build_summary(result: FolderResult, scores, baseline: str | None) -> dict:
    """summary.json: statistics per model and task, the comparison, failures, warnings, tracking quality."""
    from dataclasses import asdict

    comparison = compare_models(scores, baseline)
    return {
        "schema": SUMMARY_SCHEMA,
        "trials_id": result.folder.id,
        "trials_dir": str(result.folder.root),
        "n_trials": len(result.results) + len(result.failures),
        "n_scored": len(result.results),
        "n_failed": len(result.failures),
        "by_model": model_statistics(scores),
        "comparison": comparison,
        "failed": [{"trial_id": f.spec.id, "model": f.spec.model, "task": f.spec.task, "solution": f.spec.solution,
                    "error": f.error} for f in result.failures],
        "warnings": [{"trial_id": r.spec.id, "note": n} for r in result.results for n in r.score.notes],
        "tracking": {r.spec.id: {k: v for k, v in r.stats.items() if k != "overlay"} for r in result.results},
        "params": asdict(result.params),
    }


def _check_out(out: Path, trials_dir: Path) -> None:
    """Refuse an output inside the trials folder, or a folder that holds no earlier scores (workbench.atomic)."""
    from workbench.atomic import check_replaceable

    if out.resolve().is_relative_to(trials_dir.resolve()):
        raise ContractError("the output folder lies inside the trials folder; raw folders are never modified",
                            path=out, hint="choose another --out")
    check_replaceable(out, "score-trials")


def run_scoring(trials_dir: str | Path, out_dir: str | Path, params: ScoringSettings | None = None, *,
                trial_ids: list[str] | None = None, show_progress: bool = True) -> tuple[FolderResult, dict]:
    """Score a trials folder and write every output to ``out_dir`` atomically; returns the result and summary.

    Raises :class:`DataError` when no trial could be scored (nothing is written then).
    """
    from workbench.atomic import atomic_dir, write_json, write_text
    from workbench.trials import plots

    p = params or ScoringSettings()
    trials_dir, out = Path(trials_dir), Path(out_dir)
    _check_out(out, trials_dir)
    with atomic_dir(out, verb="score-trials") as tmp:
        result = score_folder(trials_dir, p, overlay_dir=tmp / "overlays", trial_ids=trial_ids,
                              show_progress=show_progress)
        if not result.results:
            first = result.failures[0].error if result.failures else "no trials"
            raise DataError(f"no trial could be scored ({len(result.failures)} failed); first: {first}",
                            path=result.folder.manifest)
        scores = scores_frame(score_rows(result))
        scores.write_csv(tmp / "scores.csv")
        summary = build_summary(result, scores, p.baseline)
        write_json(tmp / "summary.json", summary)
        write_text(tmp / "comparison.md", f"# Open-water trials: {result.folder.id}\n\n"
                   + comparison_markdown(scores, summary["comparison"]))
        (tmp / "trajectories").mkdir()
        for r in result.results:
            r.trajectory().write_parquet(tmp / "trajectories" / f"{r.spec.id}.parquet")
        if p.plots:
            (tmp / "plots" / "trials").mkdir(parents=True)
            plots.plot_tank(result.results, result.folder.tank, tmp / "plots" / "trajectories.png")
            plots.plot_boxplots(scores, tmp / "plots" / "boxplots.png", summary["comparison"].get("baseline"))
            for r in result.results:
                plots.plot_trial(r, tmp / "plots" / "trials" / f"{r.spec.id}.png")
        # plots/ and overlays/ always exist (pipelines declare them as outputs); a switched-off or
        # empty one says why instead of vanishing
        for sub, on, why in (("plots", p.plots, "plots are off (scoring.plots: false)"),
                             ("overlays", p.overlay, "overlays are off (scoring.overlay: false)")):
            d = tmp / sub
            d.mkdir(exist_ok=True)
            if not any(d.iterdir()):
                write_text(d / "README.txt", (why if not on else f"no {sub} were written") + "\n")
    return result, summary
