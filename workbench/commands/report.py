"""``workbench report``: one page tying the whole loop together (HTML and markdown, PNG figures)."""

from __future__ import annotations

from workbench.commands._help import add_verb


def register(sub) -> None:
    """Add the ``report`` verb."""
    p = add_verb(
        sub, "report", help="write the final report of the whole loop (HTML + markdown)",
        description="Collect campaign quality, the drag fit, EF-vs-LSTM accuracy, the optimised gaits, "
        "pool-trial scores and the model diagnosis from datasets/ into one report with the stages' "
        "figures and links to the MLflow runs, and headline.json: the loop's key numbers for "
        "`dvc metrics show/diff`. Sections whose results do not exist yet say so.",
        examples="""\
  workbench report                                  # -> datasets/reports/report.html, report.md, headline.json
  workbench report --out /tmp/rep --no-mlflow       # elsewhere, without reading the MLflow store
  xdg-open datasets/reports/report.html
""")
    p.add_argument("--datasets", default=None, help="datasets folder (default: the project's datasets/)")
    p.add_argument("--out", default=None, help="report folder (default: datasets/reports)")
    p.add_argument("--tracking-uri", default=None, help="MLflow store to link runs from (default: the project's)")
    p.add_argument("--ui-url", default="http://127.0.0.1:5000", help="where `workbench ui` serves (for links)")
    p.add_argument("--no-mlflow", action="store_true", help="skip the MLflow links")
    p.set_defaults(func=run)


def run(args) -> int:
    """Write report.html and report.md atomically."""
    from pathlib import Path

    from workbench import atomic, report
    from workbench.console import info
    from workbench.project import datasets_dir

    datasets = Path(args.datasets) if args.datasets else datasets_dir()
    out = Path(args.out) if args.out else datasets / "reports"
    out.mkdir(parents=True, exist_ok=True)
    sections = report.collect(datasets, args.tracking_uri, args.ui_url, with_mlflow=not args.no_mlflow)
    atomic.write_text(out / "report.md", report.render_markdown(sections, out))
    atomic.write_text(out / "report.html", report.render_html(sections, out))
    atomic.write_json(out / "headline.json", report.headline(datasets))
    info(f"wrote {out / 'report.html'}, report.md ({sum(len(s.figures) for s in sections)} figures) and "
         "headline.json (dvc metrics show datasets/reports/headline.json)")
    return 0
