"""The quality report on the terminal: a rich table per run (flagged runs first when there are many)."""

from __future__ import annotations

import sys
from typing import Any

#: show every run up to this many; beyond it, only skipped and flagged runs plus a summary
MAX_ROWS = 30


def summary_line(q: dict[str, Any]) -> str:
    """One line: campaign, runs ingested, ticks, drops, angle source."""
    angles = f", angles {q['angle_source']}" if q.get("angle_source") else ""
    return (f"{q['campaign_id']} ({q['facility']}): {q['runs_ingested']}/{q['runs_total']} runs, "
            f"{q['ticks']:,} ticks, dropped {q['dropped_frames']} frames / {q['dropped_bytes']} bytes{angles}")


def render_quality(q: dict[str, Any], file=None) -> None:
    """Print the quality report as a table on ``file`` (stderr by default)."""
    from rich.console import Console
    from rich.table import Table

    console = Console(file=file or sys.stderr, width=140 if not (file or sys.stderr).isatty() else None)
    runs = q["runs"]
    shown = runs if len(runs) <= MAX_ROWS else [r for r in runs if r["status"] != "ok" or r.get("flags")][:MAX_ROWS]
    table = Table(title=summary_line(q), title_justify="left", show_lines=False)
    for col, just in (("run", "left"), ("source", "left"), ("ticks", "right"), ("dropped frames/bytes", "right"),
                      ("offset ms", "right"), ("drift ppm", "right"), ("edges", "right"), ("resid ms", "right"),
                      ("flags", "left")):
        table.add_column(col, justify=just)
    for r in shown:
        if r["status"] != "ok":
            table.add_row(f"[red]{r['run_id']}[/red]", "", "", "", "", "", "", "", f"[red]skipped: {r['error']}[/red]")
            continue
        flags = list(r["flags"])
        if r["saturated"]:
            flags[flags.index("saturated")] = "saturated " + ",".join(r["saturated_samples"])
        table.add_row(r["run_id"], r["source"], f"{r['ticks']:,}", f"{r['dropped_frames']}/{r['dropped_bytes']}",
                      f"{r['clock_offset_ms']:.3f}", f"{r['clock_drift_ppm']:.1f}", str(r["edges_paired"]),
                      f"{r['edge_residual_max_ms']:.3f}", "[yellow]" + ", ".join(flags) + "[/yellow]" if flags else "")
    if shown:
        console.print(table)
    else:
        console.print(summary_line(q))
    ok = [r for r in runs if r["status"] == "ok"]
    if len(runs) > len(shown) and ok:
        import numpy as np

        off = np.array([r["clock_offset_ms"] for r in ok])
        drift = np.array([r["clock_drift_ppm"] for r in ok])
        res = np.array([r["edge_residual_max_ms"] for r in ok])
        console.print(f"{len(runs) - len(shown)} clean run(s) not listed; clock offset {off.min():.3f} .. "
                      f"{off.max():.3f} ms, drift {drift.min():.1f} .. {drift.max():.1f} ppm, "
                      f"edge residual at most {res.max():.3f} ms")
