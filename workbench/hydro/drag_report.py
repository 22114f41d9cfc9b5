"""The drag fit as a figure (points with error bars, fit, confidence band) and a short markdown report."""

from __future__ import annotations

import io

import numpy as np

from workbench.hydro.drag import DragFit, HeadingFit

_COLOURS = {"forward": "tab:blue", "lateral": "tab:orange"}


def drag_figure_png(fit: DragFit, title: str = "") -> bytes:
    """PNG bytes: both headings' run means (+- 2 SEM), fitted quadratic and its confidence band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.4), dpi=120)
    v_max = max(h.speed_range_mps[1] for h in fit.headings())
    grid = np.linspace(0.0, 1.05 * v_max, 200)
    for h in fit.headings():
        colour = _COLOURS[h.heading]
        v = np.array([p.speed_mps for p in h.points])
        f = np.array([p.drag_n for p in h.points])
        e = 2 * np.nan_to_num(np.array([p.drag_sem_n for p in h.points]))
        lo_v, hi_v = h.speed_range_mps
        inside = (grid >= lo_v) & (grid <= hi_v)
        c2, c1, c0 = h.coefficients
        ax.errorbar(v, f, yerr=e, fmt="o", ms=4, color=colour, capsize=2,
                    label=f"{h.heading} runs (n = {len(v)}, +-2 SEM)")
        ax.plot(grid[inside], h.predict(grid[inside]), color=colour,
                label=f"{c2:.2f} v^2 {c1:+.3f} v {c0:+.3f}  (R^2 {h.r2:.3f})")
        for part in (grid <= lo_v, grid >= hi_v):  # extrapolation below and above the towed range
            ax.plot(grid[part], h.predict(grid[part]), color=colour, ls=":", lw=1)
        if np.isfinite(h.t_crit):
            lo, hi = h.band(grid[inside])
            ax.fill_between(grid[inside], lo, hi, color=colour, alpha=0.2, lw=0,
                            label=f"{100 * fit.params.confidence:.0f}% confidence band")
    ax.axhline(0.0, color="0.6", lw=0.8)
    ax.set_xlabel("towing speed v (m/s)")
    ax.set_ylabel("drag F (N)")
    ax.set_xlim(0, 1.05 * v_max)
    ax.set_title(title or "body drag (dotted: extrapolation outside the towed range)", fontsize=10)
    ax.legend(fontsize=7, loc="upper left")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


def _heading_md(h: HeadingFit) -> list[str]:
    c, s = h.coefficients, h.stderr
    lo, hi = h.speed_range_mps
    lines = [f"## {h.heading}", "",
             f"F = {c[0]:.4g} v^2 {c[1]:+.4g} v {c[2]:+.4g}  (N, v in m/s), {len(h.points)} runs at "
             f"{h.n_speeds} speeds over {lo:.3f}-{hi:.3f} m/s", "",
             "| term | value | std. error |", "|---|---|---|",
             f"| c2 (N s^2/m^2) | {c[0]:.4g} | {s[0]:.3g} |",
             f"| c1 (N s/m) | {c[1]:.4g} | {s[1]:.3g} |",
             f"| c0 (N) | {c[2]:.4g} | {s[2]:.3g} |", "",
             f"R^2 = {h.r2:.4f}, chi^2/dof = {h.chi2_red:.2f} ({h.dof} dof)", ""]
    if h.flags:
        lines += ["Flags:", ""] + [f"- {f}" for f in h.flags] + [""]
    else:
        lines += ["No flags.", ""]
    lines += ["| run | speed (m/s) | drag (N) | SEM (N) | steady window (s) |", "|---|---|---|---|---|"]
    lines += [f"| {p.run_id} | {p.speed_mps:.4f} | {p.drag_n:.4f} | {p.drag_sem_n:.2g} | "
              f"{p.window_s[0]:.1f}-{p.window_s[1]:.1f} |" for p in h.points]
    return lines + [""]


def drag_report_md(fit: DragFit, source: str = "") -> str:
    """A short markdown report: the fits, their flags and the run table."""
    lines = ["# Body drag fit", ""]
    if source:
        lines += [f"Campaign: `{source}`", ""]
    n_flags = sum(len(h.flags) for h in fit.headings())
    lines += [f"{n_flags} flag(s)." if n_flags else "No physically doubtful fit found.", ""]
    for h in fit.headings():
        lines += _heading_md(h)
    if fit.skipped:
        lines += ["## Skipped runs", ""] + [f"- {r}: {why}" for r, why in fit.skipped] + [""]
    return "\n".join(lines)
