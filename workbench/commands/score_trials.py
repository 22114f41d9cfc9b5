"""``workbench score-trials``: track the robot in open-water trial videos and score each trial."""

from __future__ import annotations

from pathlib import Path

from workbench.commands._help import add_verb


def register(sub) -> None:
    """Add the ``score-trials`` verb."""
    p = add_verb(
        sub, "score-trials", help="score open-water trial videos (time, MAE, radius) and compare models",
        description="Read a trials folder (data contract section 2), find the robot's two coloured markers in "
        "every frame, map them onto the water plane through the reference points, and score each trial in "
        "its own frame: straight runs by time to 2 m and MAE(X) at the 0.25 m stations, turns by time to "
        "360 degrees and the fitted circle's radius. Writes scores.csv, summary.json (statistics per model and "
        "task, relative improvements of one model over the other, failed trials), comparison.md (a Table "
        "IV-style table), trajectories/*.parquet, plots/*.png and overlays/*.mp4. A trial that cannot be "
        "scored is listed with its error and the others are still scored; the exit status is 0 when at "
        "least one trial was scored (2 with --strict if any failed, and always 2 when none could be).",
        examples="""\
  workbench score-trials datasets/raw/demo-pool --out datasets/scores/demo-pool
  workbench score-trials datasets/raw/pool-2025-04 --out /tmp/scores --trial lstm-straight-1 --no-plots
  workbench score-trials datasets/raw/pool-2025-04 --out /tmp/scores --baseline EF --workers 1
  workbench score-trials datasets/raw/pool-2025-04 --out /tmp/scores --strict   # CI: any bad trial fails
  workbench score-trials datasets/raw/pool-2025-04 --out /tmp/scores --check    # list manifest problems
""")
    p.add_argument("trials_dir", type=Path, help="trials folder with trials.toml and videos/")
    p.add_argument("--out", type=Path, required=True, help="output folder (replaced atomically)")
    p.add_argument("--params", type=Path, default=None,
                   help="YAML with a 'scoring' section (default: pipelines/trials.yaml when it exists)")
    p.add_argument("--trial", action="append", default=None, metavar="ID", help="score only this trial (repeat)")
    p.add_argument("--baseline", default=None, help="model the others are compared against (default: EF)")
    p.add_argument("--workers", type=int, default=None, help="trials scored in parallel (processes)")
    p.add_argument("--overlay", dest="overlay", action="store_true", default=None,
                   help="write overlay videos for checking the tracking (default from params)")
    p.add_argument("--no-overlay", dest="overlay", action="store_false")
    p.add_argument("--no-plots", dest="plots", action="store_false", default=None)
    p.add_argument("--strict", action="store_true", help="exit with status 2 if any trial failed")
    p.add_argument("--check", action="store_true",
                   help="only validate trials.toml: list every violation, score nothing (--out still required)")
    p.set_defaults(func=run)


def load_scoring_params(path: Path | None):
    """The ``scoring`` section of the given file, or of pipelines/trials.yaml, or the defaults.

    A file without a ``scoring`` section (e.g. one holding only ``pool``) gives the defaults.
    """
    from workbench.params import load_settings
    from workbench.trials.params import ScoringSettings

    return load_settings(ScoringSettings, path, "scoring", default="pipelines/trials.yaml", required=False)


def run(args) -> int:
    """Score, write the outputs, report failures."""
    from workbench.console import info
    from workbench.errors import DataError
    from workbench.trials.outputs import run_scoring

    if args.check:
        return _check(args.trials_dir)
    params = load_scoring_params(args.params).replace(workers=args.workers, overlay=args.overlay,
                                                      plots=args.plots, baseline=args.baseline)
    result, summary = run_scoring(args.trials_dir, args.out, params, trial_ids=args.trial)
    info(f"scored {summary['n_scored']} of {summary['n_trials']} trials -> {args.out / 'scores.csv'}")
    for f in summary["failed"]:
        info(f"FAILED {f['trial_id']}: {f['error']}")
    for w in summary["warnings"]:
        info(f"warning {w['trial_id']}: {w['note']}")
    comp = summary["comparison"]
    for model, tasks in comp.get("models", {}).items():
        for task, entry in tasks.items():
            parts = [f"{name} {100 * v['improvement']:+.1f}%" for name, v in entry["best"].items()
                     if name != "solution" and v.get("improvement") is not None]
            if parts:
                info(f"{model} vs {comp['baseline']}, best {task}: " + ", ".join(parts))
    if args.strict and summary["failed"]:
        ids = ", ".join(f["trial_id"] for f in summary["failed"])
        raise DataError(f"{summary['n_failed']} trial(s) failed: {ids}; first: {summary['failed'][0]['error']}",
                        path=args.trials_dir / "trials.toml")
    return 0


def _check(trials_dir: Path) -> int:
    """Print every violation of trials.toml; status 0 when there is none."""
    from workbench.contract.trials import check_trials

    folder, errors, per_trial = check_trials(trials_dir)
    problems = [e.format() for e in errors] + [e.format() for errs in per_trial.values() for e in errs]
    for line in problems:
        print(line)
    if not problems:
        print(f"{trials_dir}: trials.toml is valid ({len(folder.trials)} trials)")
    return 2 if problems else 0
