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


#: the report's outputs: one set in a folder other verbs' outputs share (datasets/reports)
OUTPUTS = ("report.md", "report.html", "headline.json")


def _ours(path) -> bool:
    """A report file written before set records existed (recognised by its head)."""
    head = path.read_bytes()[:400].decode("utf-8", "replace")
    if path.name == "report.md":
        return head.startswith("# Workbench report")
    if path.name == "report.html":
        return head.startswith("<!doctype html>") and "<title>Workbench report</title>" in head
    return head.lstrip().startswith("{")  # headline.json: the loop's numbers


def run(args) -> int:
    """Write report.md, report.html and headline.json as one set (workbench.atomic.atomic_files)."""
    from pathlib import Path

    from workbench import atomic, report
    from workbench.console import info
    from workbench.project import datasets_dir

    datasets = Path(args.datasets) if args.datasets else datasets_dir()
    out = Path(args.out) if args.out else datasets / "reports"
    sections = report.collect(datasets, args.tracking_uri, args.ui_url, with_mlflow=not args.no_mlflow)
    texts = {"report.md": report.render_markdown(sections, out), "report.html": report.render_html(sections, out),
             "headline.json": atomic.json_text(report.headline(datasets))}
    with atomic.atomic_files(out, OUTPUTS, "report", recognise=_ours) as tmp:
        for name, text in texts.items():
            tmp[name].write_text(text, encoding="utf-8")
    info(f"wrote {out / 'report.html'}, report.md ({sum(len(s.figures) for s in sections)} figures) and "
         "headline.json (dvc metrics show datasets/reports/headline.json) as one set")
    return 0
