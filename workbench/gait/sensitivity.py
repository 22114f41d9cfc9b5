"""Sensitivity of gait scores and ranking to the robot constants the paper does not give (issue 14, part 4).

The full-body model needs constants the paper leaves out (docs/hydro.md, pipelines/robot.yaml marks
them "estimate"): the added masses, the yaw inertia and its added part, linear yaw damping, and
the body drag below the towed speed range. This module varies them over plausible ranges, swims
the retained gaits of a gaits file (data contract section 5) in the full-body simulator with a
leg force model (EF by default), scores them on the task they were optimised on
(``S = w1 f1 + w2 f2 + w3 f3``, workbench.gait.objectives) and computes Sobol indices
(``scipy.stats.sobol_indices``, Saltelli/Jansen estimators) of

* each retained gait's score, and
* the ranking's agreement with the nominal ranking (Kendall's tau of the scores).

Every simulation's convergence is checked (``Trajectory.converged``): a gait that did not converge
in some sample has no score there, its indices are not computed and the result lists it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from workbench.errors import ConvergenceError, SettingError


@dataclass(frozen=True)
class Factor:
    """One uncertain constant: its name, unit, plausible range and why."""

    name: str
    low: float
    high: float
    unit: str
    why: str


#: Plausible ranges of the estimated constants (nominal values in pipelines/robot.yaml).
FACTORS = (
    Factor("added_mass_forward_kg", 0.1, 0.4, "kg", "5-20 % of the ~2 kg displaced mass in surge"),
    Factor("added_mass_lateral_kg", 0.5, 1.6, "kg", "a floating box in sway: 0.25-0.8 x displaced mass"),
    Factor("yaw_inertia_kgm2", 0.022, 0.045, "kg m^2", "m (L^2 + W^2) / 12 with the mass 1.6-2.5 kg and foam"),
    Factor("added_yaw_inertia_kgm2", 0.005, 0.025, "kg m^2", "lateral added mass over the length, m_a L^2 / 12"),
    Factor("extra_yaw_damping_nms", 0.0, 0.02, "N m s", "linear yaw damping beyond strip theory (legs, appendages)"),
    Factor("drag_linear_below_mps", 0.001, 0.10, "m/s",
           "drag below the towed range (0.10 m/s): below this speed the drag runs linearly to zero from the "
           "law's value there (viscous-like) instead of following c2 v^2 + c1 v; 0.001 is the nominal law")
)


def robot_with(robot, values: dict):
    """A copy of ``robot`` (RobotSettings) with the factors' values applied."""
    from workbench.hydro.robot import DragLaw

    kw = {k: float(v) for k, v in values.items() if k != "drag_linear_below_mps"}
    r = replace(robot, **kw)
    if "drag_linear_below_mps" in values:
        v_lin = float(values["drag_linear_below_mps"])
        laws = {}
        for name in ("forward_drag", "lateral_drag"):
            law = getattr(r, name)
            c2, c1, c0 = law.coefficients
            # the in-range law stays as configured (drop_intercept: c0 is a towing artefact)
            c0 = 0.0 if law.below_range == "drop_intercept" else c0
            laws[name] = DragLaw((c2, c1, c0), (v_lin, law.speed_range_mps[1]), below_range="linear_to_zero")
        r = replace(r, **laws)
    return r


def _kendall(a: np.ndarray, b: np.ndarray) -> float:
    from scipy.stats import kendalltau

    return float(kendalltau(a, b).statistic)


@dataclass
class SensitivityResult:
    """Sobol indices and what they were computed from (``to_dict`` for sensitivity.json)."""

    factors: tuple[Factor, ...]
    labels: list[str]
    nominal_scores: np.ndarray
    #: (n_evaluations, n_gaits) scores; NaN where the simulation did not converge
    scores: np.ndarray
    taus: np.ndarray
    #: output name -> (first (d,), total (d,), (first low, high), (total low, high)) 90 % bootstrap
    #: intervals; None when the output had unconverged samples
    indices: dict
    unconverged: dict
    n: int
    task: str

    def to_dict(self) -> dict:
        """The JSON-ready summary: factors, nominal scores and spread, ranking stability, indices."""
        def idx(v):
            if v is None:
                return None
            names = [f.name for f in self.factors]
            out = {"first_order": dict(zip(names, map(float, v[0]), strict=True)),
                   "total_order": dict(zip(names, map(float, v[1]), strict=True))}
            if len(v) > 2:
                for key, (lo, hi) in (("first_order_ci90", v[2]), ("total_order_ci90", v[3])):
                    out[key] = {nm: [float(a), float(b)] for nm, a, b in zip(names, lo, hi, strict=True)}
            return out

        best = np.nanargmin(self.scores, axis=1) if np.isfinite(self.scores).any() else []
        return {
            "task": self.task, "n_base_samples": self.n, "n_simulations": int(self.scores.shape[0]),
            "factors": [{"name": f.name, "low": f.low, "high": f.high, "unit": f.unit, "why": f.why}
                        for f in self.factors],
            "gaits": self.labels,
            "nominal_scores": [float(s) for s in self.nominal_scores],
            "score_spread": {lab: {"min": float(np.nanmin(self.scores[:, i])), "max": float(np.nanmax(self.scores[:, i]))}
                             for i, lab in enumerate(self.labels)},
            "ranking": {"kendall_tau_min": float(np.nanmin(self.taus)), "kendall_tau_mean": float(np.nanmean(self.taus)),
                        "nominal_best_stays_best_fraction":
                            float(np.mean(np.asarray(best) == int(np.argmin(self.nominal_scores))))},
            "indices": {k: idx(v) for k, v in self.indices.items()},
            "unconverged_samples": self.unconverged,
        }


def run_sensitivity(gaits, labels, leg_model, robot, task_spec, *, n: int = 16, seed: int = 0,
                    settings: dict | None = None, factors=FACTORS, progress=None) -> SensitivityResult:
    """Sobol study of the gait scores over ``factors``; ``n`` base samples (a power of 2), n (d + 2) simulations."""
    from scipy.stats import sobol_indices, uniform

    from workbench.gait.objectives import objectives, score
    from workbench.hydro.simulator import simulate

    if n < 2 or n & (n - 1):
        raise SettingError(f"n = {n}: the Sobol design needs a power of 2 base samples (8, 16, 32, ...)")
    settings = dict(settings or {})
    settings.setdefault("duration_s", task_spec.cap_s)
    names = [f.name for f in factors]
    calls = {"done": 0}

    def scores_at(values: dict) -> tuple[np.ndarray, np.ndarray]:
        traj = simulate(gaits, leg_model, robot_with(robot, values), **settings)
        s = score(objectives(traj, task_spec), task_spec.weights)
        return np.where(traj.converged, s, np.nan), traj.converged

    nominal, conv = scores_at({})
    if not conv.all():
        bad = [labels[i] for i in np.flatnonzero(~conv)]
        raise ConvergenceError(f"the nominal robot's simulation did not converge for {', '.join(bad)}",
                               hint="see the simulation settings of the robot file, docs/hydro.md")
    rows: list[np.ndarray] = []

    def func(x: np.ndarray) -> np.ndarray:
        out = np.empty((len(labels) + 1, x.shape[1]))
        for j in range(x.shape[1]):
            s, _ = scores_at(dict(zip(names, x[:, j], strict=True)))
            rows.append(s)
            ok = np.isfinite(s)
            out[:-1, j] = s
            out[-1, j] = _kendall(s[ok], nominal[ok]) if ok.sum() >= 2 else np.nan
            calls["done"] += 1
            if progress is not None:
                progress(calls["done"])
        return out

    # an unconverged gait scores NaN in that sample: its indices come out NaN and are reported as missing
    dists = [uniform(loc=f.low, scale=f.high - f.low) for f in factors]
    res_all = sobol_indices(func=func, n=n, dists=dists, random_state=np.random.default_rng(seed))
    first, total = np.atleast_2d(res_all.first_order), np.atleast_2d(res_all.total_order)
    # 90 % bootstrap intervals (no new simulations): small designs give noisy indices, say how noisy
    import warnings

    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # BCa warns when a factor does nothing (degenerate resamples)
        boot = res_all.bootstrap(confidence_level=0.9, n_resamples=499)
    ci = [np.atleast_2d(getattr(boot, k).confidence_interval.low) for k in ("first_order", "total_order")]
    ci += [np.atleast_2d(getattr(boot, k).confidence_interval.high) for k in ("first_order", "total_order")]
    allrows = np.array(rows)
    taus = np.array([_kendall(r[np.isfinite(r)], nominal[np.isfinite(r)]) if np.isfinite(r).sum() >= 2 else np.nan
                     for r in allrows])
    indices, unconverged = {}, {}
    for i, lab in enumerate(labels + ["ranking_kendall_tau"]):
        col = allrows[:, i] if i < len(labels) else taus
        bad = int(np.sum(~np.isfinite(col)))
        if bad:
            unconverged[lab] = bad
            indices[lab] = None
        else:
            indices[lab] = (first[i], total[i], (ci[0][i], ci[2][i]), (ci[1][i], ci[3][i]))
    return SensitivityResult(tuple(factors), list(labels), nominal, allrows, taus, indices, unconverged, n,
                             task_spec.task)


def figure_png(result: SensitivityResult) -> bytes:
    """Bar chart: first-order and total Sobol indices of each factor for each gait's score and the ranking."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [f.name for f in result.factors]
    outs = [k for k, v in result.indices.items() if v is not None]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    width = 0.8 / max(len(outs), 1)
    for ax, which, title in ((axes[0], 0, "first-order index S1"), (axes[1], 1, "total index ST")):
        for j, k in enumerate(outs):
            vals = np.clip(result.indices[k][which], 0, None)
            ax.bar(np.arange(len(names)) + j * width - 0.4 + width / 2, vals, width,
                   label=k, color="k" if k == "ranking_kendall_tau" else None)
        ax.set_xticks(np.arange(len(names)), [n.replace("_", "\n", 2) for n in names], fontsize=7)
        ax.set_title(title)
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_ylabel("share of the output's variance")
    axes[1].legend(fontsize=6, ncol=2)
    fig.suptitle(f"Sensitivity of the {result.task} gait scores and ranking to the estimated robot constants "
                 f"({result.scores.shape[0]} simulations)", fontsize=9)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()
