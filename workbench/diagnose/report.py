"""The readable diagnosis: ``report.md`` with PNG figures (residuals, spectra, correlations, evidence per claim).

Only the figure and text rendering lives here; the numbers come from a
:class:`~workbench.diagnose.loop.Diagnosis`. Nothing is written: :func:`render_report` returns the
files as ``{relative name: text or PNG bytes}`` and the ``diagnose`` command writes them as one set.
"""

from __future__ import annotations

import io

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS

CHANNELS = list(WRENCH_CHANNELS)


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png(fig, plt) -> bytes:
    """The figure as PNG bytes (as ``savefig(path, dpi=90)`` would write them), then closed."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def _example_runs(d, n: int) -> list[int]:
    """Held-out runs with the largest error removed (the clearest before/after), at most ``n``."""
    pairs = []
    for i, (rb, ra) in enumerate(zip(d.residuals_before, d.residuals_after, strict=False)):
        if not rb.heldout or rb.fit.sum() < 8:
            continue
        mb = (rb.resid[rb.fit] ** 2).mean(axis=0)
        ma = (ra.resid[ra.fit] ** 2).mean(axis=0)
        pairs.append((float(np.mean((mb - ma) / np.maximum(mb, 1e-300))), i))
    pairs.sort(reverse=True)
    return [i for _, i in pairs[:n]]


def fig_residuals(d, n_runs: int = 3) -> bytes | None:
    """Measured, model and augmented model on example held-out runs, every channel."""
    plt = _plt()
    runs = _example_runs(d, n_runs)
    if not runs:
        return None
    fig, axes = plt.subplots(6, len(runs), figsize=(4.2 * len(runs), 11), sharex="col", squeeze=False)
    for j, i in enumerate(runs):
        rb, ra = d.residuals_before[i], d.residuals_after[i]
        t = rb.time_s
        for c in range(6):
            ax = axes[c, j]
            ax.plot(t, rb.measured[:, c], color="0.2", lw=1.0, label="measured")
            ax.plot(t, rb.predicted[:, c], color="tab:red", lw=0.9, label=d.model)
            ax.plot(t, ra.predicted[:, c], color="tab:blue", lw=0.9, ls="--", label=f"{d.model} + effects")
            ax.axvspan(t[0], t[rb.fit][0] if rb.fit.any() else t[0], color="0.9", zorder=0)
            if j == 0:
                ax.set_ylabel(CHANNELS[c])
            if c == 0:
                ax.set_title(f"{rb.run_id}: U = {rb.flow:.2f} m/s, f = {rb.freq:.2f} Hz", fontsize=9)
        axes[-1, j].set_xlabel("time since first trigger edge (s)")
    axes[0, 0].legend(fontsize=7, loc="upper right")
    fig.suptitle("Held-out runs: measured, diagnosed model, augmented model (grey: not analysed)")
    fig.tight_layout()
    return _png(fig, plt)


def fig_spectra(d) -> bytes:
    """Spectrum of the residual's non-stroke-locked part, before and after, with lines and gait harmonics."""
    plt = _plt()
    eb, ea = d.evidence_before, d.evidence_after
    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5))
    gait = sorted({round(r.freq, 3) for r in d.residuals_before if np.isfinite(r.freq)})
    ev = d.settings.evidence
    fmax = max(1.3 * ev.fmax_hz, ev.lines_fmax_hz + 0.3)  # lines are looked for past the low-pass cutoff
    kb, ka = eb.freqs <= fmax, ea.freqs <= fmax
    for c, ax in enumerate(axes.ravel()):
        ax.semilogy(eb.freqs[kb], eb.psd_rest[kb, c], color="tab:red", lw=1, label="before")
        ax.semilogy(ea.freqs[ka], ea.psd_rest[ka, c], color="tab:blue", lw=1, label="after")
        ax.semilogy(ea.freqs[ka], ea.floor[ka, c], color="0.5", lw=0.8, ls=":", label="floor (after)")
        if gait:
            for k in range(1, 13):
                ax.axvline(k * gait[0], color="0.85", lw=0.6, zorder=0)
        for p in eb.peaks:
            if CHANNELS[c] in p.channels:
                ax.axvline(p.frequency_hz, color="tab:orange", lw=1.2, ls="--")
        ax.set_xlim(0, fmax)
        ax.set_title(CHANNELS[c], fontsize=9)
        ax.set_xlabel("Hz")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Welch spectrum of the residual less its stroke-locked part (orange: lines; grey: harmonics "
                 f"of {gait[0] if gait else '?'} Hz)")
    fig.tight_layout()
    return _png(fig, plt)


def fig_correlations(d) -> bytes:
    """Autocorrelation and cross-correlation with the model force's rate, before and after, with bounds."""
    plt = _plt()
    eb, ea = d.evidence_before, d.evidence_after
    fig, axes = plt.subplots(2, 6, figsize=(17, 5.5), sharey="row")
    for c in range(6):
        ax = axes[0, c]
        ax.plot(eb.acf_lags_s, eb.acf[:, c], color="tab:red", label="before")
        ax.plot(ea.acf_lags_s, ea.acf[:, c], color="tab:blue", label="after")
        ax.axhspan(-ea.acf_bound, ea.acf_bound, color="0.85")
        ax.set_title(f"{CHANNELS[c]} autocorrelation", fontsize=8)
        ax = axes[1, c]
        for ev, col in ((eb, "tab:red"), (ea, "tab:blue")):
            cc = ev.ccf.get("model_force_rate")
            if cc:
                ax.plot(cc["lags_s"], cc["r"][:, c], color=col)
                ax.fill_between(cc["lags_s"], -cc["bound"][:, c], cc["bound"][:, c], color=col, alpha=0.12)
        ax.set_title(f"{CHANNELS[c]} x d(model)/dt", fontsize=8)
        ax.set_xlabel("lag (s)")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle("Whiteness (bounds: white noise) and cross-correlation with the model force's rate "
                 "(bands: Bartlett bounds, 99 %)")
    fig.tight_layout()
    return _png(fig, plt)


def fig_dependence(d) -> bytes:
    """Residual against flow speed, hip angle, stroke phase and time in the run."""
    plt = _plt()
    eb, ea = d.evidence_before, d.evidence_after
    fig, axes = plt.subplots(1, 4, figsize=(17, 3.8))
    speeds = sorted(eb.by_flow, key=float)
    mb = np.array([[eb.by_flow[u][ch] for ch in CHANNELS] for u in speeds])
    ma = np.array([[ea.by_flow[u][ch] for ch in CHANNELS] for u in speeds])
    x = np.array([float(u) for u in speeds])
    for c, ch in enumerate(CHANNELS[:3]):
        axes[0].semilogy(x, mb[:, c], "o-", label=f"{ch} before")
        axes[0].semilogy(x, ma[:, c], "s--", label=f"{ch} after")
    axes[0].set_xlabel("flow speed (m/s)")
    axes[0].set_ylabel("held + training MSE")
    axes[0].legend(fontsize=6)
    for ax, key, xl in ((axes[1], "by_angle", "theta_h (deg)"), (axes[2], "by_phase", "stroke phase (cycles)")):
        for ev, ls in ((eb, "-"), (ea, "--")):
            b = getattr(ev, key)
            for c in range(3):
                ax.plot(b["centers"], b["mean"][:, c], ls, color=f"C{c}")
        ax.set_xlabel(xl)
        ax.set_ylabel("mean residual (N)")
    for ev, col in ((eb, "tab:red"), (ea, "tab:blue")):
        slopes = [ev.trend[ch]["t"] for ch in CHANNELS]
        axes[3].bar(np.arange(6) + (0 if col == "tab:red" else 0.4), slopes, 0.4, color=col)
    axes[3].set_xticks(np.arange(6) + 0.2, [c.split("_")[0] for c in CHANNELS])
    axes[3].axhline(3.3, color="0.5", ls=":")
    axes[3].axhline(-3.3, color="0.5", ls=":")
    axes[3].set_ylabel("t of the within-run trend")
    fig.suptitle("Dependence of the residual (solid / red: before, dashed / blue: after)")
    fig.tight_layout()
    return _png(fig, plt)


def fig_effect(d, eff) -> bytes:
    """One claimed effect: its search profile (nonlinear) and the held-out error it removes per channel."""
    plt = _plt()
    prof = d.profiles.get(eff.name)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    if prof and prof.get("points"):
        pts = np.array(prof["points"], float)
        sse = np.array(prof["sse"], float)
        axes[0].scatter(pts[:, 0], sse, c=np.log(pts[:, 1]) if pts.shape[1] > 1 else "tab:blue", s=14)
        axes[0].set_xlabel(prof["params"][0])
        axes[0].set_ylabel("training SSE (weighted)")
        axes[0].set_xscale("log" if np.all(pts[:, 0] > 0) and pts[:, 0].max() / pts[:, 0].min() > 20 else "linear")
        axes[0].set_title("search profile", fontsize=9)
    else:
        axes[0].text(0.5, 0.5, "linear in its parameters:\nleast squares", ha="center", va="center")
        axes[0].axis("off")
    red = [eff.heldout_mse_reduction_by_channel[c] for c in CHANNELS]
    axes[1].bar([c.split("_")[0] for c in CHANNELS], red, color="tab:green")
    axes[1].set_ylabel("share of held-out MSE removed")
    params = ", ".join(f"{k} = {v:.4g}" for k, v in eff.params.items() if isinstance(v, float))
    fig.suptitle(f"{eff.name}: {params}", fontsize=10)
    fig.tight_layout()
    return _png(fig, plt)


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def markdown(d, figures: dict[str, str], truth: dict | None = None) -> str:
    """The report text."""
    j = d.to_json()
    lines = _error_table(d)
    lines += ["", "## Effects claimed (best first)", ""]
    for note in d.not_converged():
        lines += [f"**Not converged:** {note}.", ""]
    if not d.effects:
        lines.append("None: no candidate beat the noise on held-out runs.")
    for e in d.effects:
        lines += _effect_section(e, figures, (truth or {}).get(e.name) or {})
    lines += ["## Unexplained", ""]
    if not d.unexplained:
        lines.append("Nothing: the residual left is consistent with the rig's noise.")
    for u in d.unexplained:
        f = f" at {u.frequency_hz:.2f} Hz" if u.frequency_hz is not None else ""
        lines.append(f"- **{u.kind}**{f} in {', '.join(u.channels)}: {u.evidence}")
    lines += _evidence_section(j["evidence_before"], j["evidence_after"], figures)
    lines += _selection_section(j["selection"])
    lines += ["Method and effect library: docs/diagnose.md.", ""]
    return "\n".join(lines)


def _error_table(d) -> list[str]:
    """Title, the runs, the reference campaign if any, and the held-out error per channel before and after."""
    lines = [f"# Diagnosis of `{d.model}` on `{d.campaign_id}`", "",
             f"{len(d.train_runs)} training runs, {len(d.heldout_runs)} held-out runs (chosen from the motion "
             f"parameters, every flow speed of a set on the same side); {d.runtime_s:.1f} s.", ""]
    if d.reference:
        r = d.reference
        lines += [f"Against reference campaign `{r['campaign']}`: the base model's stroke-locked misfit there "
                  f"({r['matched_runs']} runs matched exactly, {r['nearest_neighbour_runs']} by nearest "
                  "parameters) is part of the prediction, so only what changed since is diagnosed.", ""]
    lines += ["## Error on held-out runs", "", "| channel | MSE before | MSE after | removed |", "|---|---|---|---|"]
    for c in CHANNELS:
        b, a = d.mse_before[c], d.mse_after[c]
        lines.append(f"| {c} | {b:.4g} | {a:.4g} | {(1 - a / b) if b > 0 else 0:.0%} |")
    return lines


def _effect_section(e, figures: dict[str, str], true: dict) -> list[str]:
    """One claimed effect: its evidence, held-out reduction, parameter table (beside ``true``), notes and figure."""
    ej = e.to_json()
    lines = [f"### {e.name}", "", f"*{e.evidence}*", "",
             f"Held-out MSE reduction (mean over channels, as a share of the model's error): "
             f"**{e.heldout_mse_reduction:.1%}**; channels: {', '.join(e.channels) or '-'}.", "",
             "| parameter | value | std. error | 95 % interval | virtual truth |", "|---|---|---|---|---|"]
    for k, v in e.params.items():
        ci = ej["ci95"].get(k)
        lines.append(f"| {k} | {_fmt(v)} | {_fmt(e.stderr.get(k))} | "
                     f"{'-' if not ci else f'[{_fmt(ci[0])}, {_fmt(ci[1])}]'} | {_fmt(true.get(k))} |")
    lines.append("")
    for n in e.notes:
        lines.append(f"- {n}")
    if e.name in figures:
        lines += ["", f"![{e.name}]({figures[e.name]})", ""]
    return lines


def _evidence_section(eb: dict, ea: dict, figures: dict[str, str]) -> list[str]:
    """The residual evidence before and after per channel, the residual lines, and the evidence figures."""
    lines = ["", "## Residual evidence", "",
             "| channel | stroke-locked share before | after | power at gait harmonics / noise before | after |"
             " trend t before | after |", "|---|---|---|---|---|---|---|"]
    for c in CHANNELS:
        lines.append(f"| {c} | {_fmt(eb['gait_locked_share'][c])} | {_fmt(ea['gait_locked_share'][c])} | "
                     f"{_fmt(eb['gait_locked_power_ratio'][c])} | {_fmt(ea['gait_locked_power_ratio'][c])} | "
                     f"{_fmt(eb['trend_t'][c])} | {_fmt(ea['trend_t'][c])} |")
    before = ", ".join("{} Hz ({})".format(p["frequency_hz"], ", ".join(p["channels"]))
                       for p in eb["narrowband_peaks"]) or "none"
    after = ", ".join("{} Hz".format(p["frequency_hz"]) for p in ea["narrowband_peaks"]) or "none"
    lines += ["", f"Residual lines before: {before}; after: {after}.",
              f"Zero-flow runs: {eb['zero_flow'].get('runs', 0)}; runs with a rest stretch: "
              f"{eb['rest'].get('runs', 0)}.", ""]
    for key, title in (("residuals", "Held-out runs before and after"), ("spectra", "Spectra"),
                       ("correlations", "Whiteness and cross-correlation"), ("dependence", "Dependence")):
        if key in figures:
            lines += [f"### {title}", "", f"![{key}]({figures[key]})", ""]
    return lines


def _selection_section(selection: list[dict]) -> list[str]:
    """The selection record: every step's candidates with their held-out test and verdict."""
    lines = ["## Selection, step by step", "",
             "Each step fits every remaining candidate on the training runs and judges it on the held-out "
             "runs (t: one-sided test of the held-out log-likelihood gain per block, Newey-West variance; "
             "claimed when p is below alpha over the number of candidates, the gain is at least the "
             "minimum in some channel and the structural checks pass).", ""]
    for st in selection:
        lines += [f"**Step {st['step']}**{' (stopped)' if st.get('stopped') else ''}", "",
                  "| candidate | t | p | held-out LLR | best channel gain | claimed | why not |", "|---|---|---|---|---|---|---|"]
        for c in st["candidates"]:
            lines.append(f"| {c['label']} | {c['t']:.2f} | {c['p']:.2g} | {c['llr']:.1f} | {c['max_gain']:.1%} | "
                         f"{'yes' if c['ok'] else ''} | {c['note']} |")
        lines.append("")
    return lines


def render_report(d, figures: bool = True, truth: dict | None = None) -> dict[str, str | bytes]:
    """``report.md`` and its figures as ``{name relative to the output folder: text or PNG bytes}``.

    ``figures=False``: the text alone. ``truth``: for a virtual campaign, the values its ground
    truth gives each effect's parameters (:func:`workbench.diagnose.library.truth_reference`),
    shown beside the fitted ones. The ``diagnose`` command writes the files atomically as one set.
    """
    made: dict[str, str] = {}
    files: dict[str, str | bytes] = {}
    if figures:
        pngs = [("residuals", fig_residuals(d, d.settings.report.example_runs)), ("spectra", fig_spectra(d)),
                ("correlations", fig_correlations(d)), ("dependence", fig_dependence(d))]
        for key, png in pngs:
            if png is not None:
                made[key] = f"figures/{key}.png"
                files[made[key]] = png
        for e in d.effects:
            made[e.name] = f"figures/effect_{e.name}.png"
            files[made[e.name]] = fig_effect(d, e)
    files["report.md"] = markdown(d, made, truth)
    return files
