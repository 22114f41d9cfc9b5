"""The report's page: sections, captions, number format, and the markdown and HTML renderings.

A section holds a title, paragraphs, tables, figures and links; figures are linked relative to
the report folder.
"""

from __future__ import annotations

import html
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: pool labels of the pipeline's model keys (the virtual pool's truth.json says so too)
MODEL_LABELS = {"ef": "EF", "lstm": "FED-LSTM", "lstm16": "FED-LSTM-16"}


@dataclass
class Section:
    """One part of the report: a title, paragraphs, tables and figures."""

    title: str
    paragraphs: list[str] = field(default_factory=list)
    #: tables as (caption, header, rows)
    tables: list[tuple[str, list[str], list[list[str]]]] = field(default_factory=list)
    #: figures as paths (captioned by :func:`caption`) or (path, caption)
    figures: list[Path | tuple[Path, str]] = field(default_factory=list)
    links: list[tuple[str, str]] = field(default_factory=list)


#: what each stage's figure shows, by file name; "{what}" is filled from the folder (task and model)
FIGURE_CAPTIONS = {
    "drag.png": "Towing-tank drag force against towing speed with the quadratic fit and its residuals ({what})",
    "hypervolume.png": "Hypervolume of the Pareto front after each NSGA-II generation ({what}; higher is better)",
    "pareto.png": "Final Pareto front of the three objectives, retained gaits marked ({what})",
    "trajectories.png": "Simulated 60 s paths of the retained gaits, start at the origin ({what})",
    "mse_boxplot.png": "Held-out MSE per run, EF against the learned model, per channel (N^2 for forces, "
                       "(N m)^2 for torques; log scale)",
    "prediction_a.png": "Measured and predicted wrench over the last cycles of a held-out run (the paper's Fig. 4 set a)",
    "prediction_b.png": "Measured and predicted wrench over the last cycles of a held-out run (the paper's Fig. 4 set b)",
    "sensitivity.png": "Total Sobol indices of the estimated robot constants for each retained gait's score and "
                       "for the ranking ({what})",
    "boxplots.png": "Pool-trial scores per model and task (unfinished trials drawn apart, not as 60 s times)",
    "learning_curve.png": "Training and validation loss per epoch ({what})",
    "trajectory_errors.png": "RMS position and heading error of each leg model's swims against the tracked pool "
                             "trials, each trial in its own frame",
}


def _what(path: Path) -> str:
    """A figure's subject from its folder name: ``straight-lstm`` -> ``straight task, FED-LSTM``."""
    name = path.parent.name
    if name in ("plots",):
        name = path.parent.parent.name
    task, _, model = name.partition("-")
    if task in ("straight", "turn") and model:
        return f"{task} task, {MODEL_LABELS.get(model, model)}"
    return name


def caption(path: Path) -> str:
    """The caption of a stage figure: what it shows, not its file name."""
    if path.parent.name == "plots" and path.name == "trajectories.png":
        return f"Pool trajectories scored from the overhead videos, per model and task ({path.parent.parent.name})"
    text = FIGURE_CAPTIONS.get(path.name)
    if text is None:
        return path.stem.replace("_", " ").capitalize() + f" ({_what(path)})"
    return text.format(what=_what(path))


def _figure(f: Path | tuple[Path, str]) -> tuple[Path, str]:
    return (f[0], f[1]) if isinstance(f, tuple) else (f, caption(f))


def fmt(v: Any, digits: int = 3) -> str:
    """A table cell: ``-`` for nothing, floats to ``digits`` (scientific when tiny or huge)."""
    if v is None or v == "":
        return "-"
    if isinstance(v, float):
        if v != 0 and (abs(v) < 1e-3 or abs(v) >= 1e5):
            return f"{v:.{digits}e}"
        return f"{v:.{digits}f}"
    return str(v)


def _rel(path: Path, out_dir: Path) -> str:
    return Path(os.path.relpath(path.resolve(), out_dir.resolve())).as_posix()


def render_markdown(sections: list[Section], out_dir: Path, title: str = "Workbench report") -> str:
    """The report as markdown, figure links relative to ``out_dir``."""
    lines = [f"# {title}", ""]
    for s in sections:
        lines += [f"## {s.title}", ""]
        for p in s.paragraphs:
            lines += [p, ""]
        for caption, header, rows in s.tables:
            lines += [f"*{caption}*", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            lines += ["| " + " | ".join(str(c).replace("|", "/") for c in r) + " |" for r in rows]
            lines.append("")
        for f in s.figures:
            path, cap = _figure(f)
            lines += [f"![{cap}]({_rel(path, out_dir)})", "", f"*Figure: {cap}.*", ""]
        for label, url in s.links:
            lines.append(f"- [{label}]({url})")
        if s.links:
            lines.append("")
    return "\n".join(lines)


def render_html(sections: list[Section], out_dir: Path, title: str = "Workbench report") -> str:
    """The report as one HTML page (no scripts, no network), figures linked relative to ``out_dir``."""
    import re

    def md_inline(text: str) -> str:
        t = html.escape(text)
        t = re.sub(r"\*\*(.+?)\*\*", r"<b>\1</b>", t)
        return re.sub(r"`(.+?)`", r"<code>\1</code>", t)

    out = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
           "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;padding:0 1em}"
           "table{border-collapse:collapse;margin:.5em 0 1.5em}td,th{border:1px solid #ccc;padding:3px 8px;"
           "font-size:90%}th{background:#f3f3f3}img{max-width:100%;margin:.5em 0;border:1px solid #eee}"
           "pre{white-space:pre-wrap}</style></head><body>", f"<h1>{html.escape(title)}</h1>"]
    out.append("<p>" + " &middot; ".join(f"<a href='#s{i}'>{html.escape(s.title)}</a>"
                                          for i, s in enumerate(sections)) + "</p>")
    for i, s in enumerate(sections):
        out.append(f"<h2 id='s{i}'>{html.escape(s.title)}</h2>")
        for p in s.paragraphs:
            out.append(f"<pre>{md_inline(p)}</pre>" if "\n" in p else f"<p>{md_inline(p)}</p>")
        for caption, header, rows in s.tables:
            out.append(f"<table><caption>{html.escape(caption)}</caption><tr>"
                       + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>")
            out += ["<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows]
            out.append("</table>")
        for f in s.figures:
            path, cap = _figure(f)
            out.append(f"<figure><img src='{html.escape(_rel(path, out_dir))}' alt='{html.escape(cap)}'>"
                       f"<figcaption>{html.escape(cap)}</figcaption></figure>")
        if s.links:
            out.append("<ul>" + "".join(f"<li><a href='{html.escape(u)}'>{html.escape(lbl)}</a></li>"
                                        for lbl, u in s.links) + "</ul>")
    out.append("</body></html>")
    return "\n".join(out)
