"""Tunnel blockage: the flow the leg meets is faster than the set speed (``tunnel_blockage``; docs/diagnose.md).

Maskell's prior applies when the manifest gives the tunnel's cross-section.
"""

from __future__ import annotations

import numpy as np

from workbench.diagnose.effects.base import Context, Effect, SearchParam, Terms
from workbench.hydro.motion import LegMotion


class TunnelBlockage(Effect):
    """Free-stream dynamic pressure raised by (1 + epsilon): U_eff = U sqrt(1 + epsilon).

    Acts on the flow every term sees (the model, a drag error, lift, ...), like the tunnel does;
    epsilon is found by a 1-D search wrapping the linear fit.
    """

    name = "tunnel_blockage"
    ranges = {"epsilon": (-0.1, 0.5)}
    stage = "input"
    physical = False
    formula = "U_eff = U sqrt(1 + epsilon)"
    search = (SearchParam("epsilon", (-0.06, -0.02, 0.02, 0.05, 0.08, 0.12, 0.18, 0.3), (-0.5, 1.5)),)
    surrogate_ok = True

    def __init__(self, test_section_area_m2: float | None = None, theta: float = 2.5, c_d: float = 1.17,
                 prior_width: float = 0.5):
        """``test_section_area_m2``: the tunnel's cross-section; given, epsilon takes Maskell's prior.

        With a cross-section each run's blockage is Maskell's ``theta C_D S_run / C``
        (``workbench.diagnose.maskell``) times ``1 + d_maskell``, one factor for the campaign,
        fitted by least squares with the Gaussian prior ``d_maskell ~ N(0, prior_width^2)`` (a ridge
        toward Maskell's value). Without one, nothing changes: one epsilon, searched.
        """
        if test_section_area_m2 is not None and not (float(test_section_area_m2) > 0):
            from workbench.errors import ModelError

            raise ModelError(f"tunnel_blockage: test_section_area_m2 must be positive, got {test_section_area_m2!r}")
        if not (theta > 0 and c_d > 0 and prior_width > 0):
            from workbench.errors import ModelError

            raise ModelError("tunnel_blockage: theta, c_d and prior_width must be positive")
        self.area = None if test_section_area_m2 is None else float(test_section_area_m2)
        self.theta, self.c_d, self.prior_width = float(theta), float(c_d), float(prior_width)
        self._eps: dict[str, float] = {}
        if self.area is not None:
            self.stage, self.search, self.surrogate_ok = "force", (), False
            self.formula = "U_eff = U sqrt(1 + epsilon_run), epsilon_run = (1 + d_maskell) theta C_D S_run / C"

    def options(self) -> dict:  # noqa: D102
        if self.area is None:
            return {}
        return {"test_section_area_m2": self.area, "theta": self.theta, "c_d": self.c_d,
                "prior_width": self.prior_width}

    def linear_names(self):  # noqa: D102
        return ["d_maskell"] if self.area is not None else []

    def priors(self) -> dict[str, tuple[float, float]]:
        """Gaussian priors (mean, sd) of linear parameters: Maskell's factor, when a cross-section is known."""
        return {"d_maskell": (0.0, self.prior_width)} if self.area is not None else {}

    def force_terms(self, ctx: Context, nl: dict) -> Terms:  # noqa: D102
        if self.area is None:
            return Terms()
        from workbench.diagnose.maskell import blockage_terms, prior_epsilon, run_flow

        eps = prior_epsilon(ctx, self.area, self.theta, self.c_d)
        for rid, e, u in zip(getattr(ctx.rs, "run_ids", ()), eps, run_flow(ctx), strict=False):
            if u > 0:
                self._eps[rid] = float(e)
        fixed, col = blockage_terms(ctx, eps)
        return Terms(["d_maskell"], [col], [np.ones(6, bool)], fixed=fixed)

    def canonical_params(self, coefs, nl, cov, local=None):  # noqa: D102
        if self.area is None:
            return super().canonical_params(coefs, nl, cov, local)
        from workbench.diagnose.maskell import data_alone

        prior = float(np.mean(list(self._eps.values()))) if self._eps else float("nan")
        d = float(coefs.get("d_maskell", 0.0))
        var = float(cov.get(("d_maskell", "d_maskell"), np.nan))
        params = {"epsilon": prior * (1 + d), "epsilon_prior": prior, "epsilon_prior_sd": prior * self.prior_width,
                  "epsilon_data": None, "d_maskell": d}
        se = {"epsilon": abs(prior) * float(np.sqrt(max(var, 0.0))) if np.isfinite(var) else float("nan")}
        alone = data_alone(d, var, self.prior_width)
        if alone is not None:
            params["epsilon_data"] = prior * (1 + alone[0])
        return params, se

    def flow_factor(self, nl: dict) -> float:
        """U_eff / U."""
        if self.area is not None:
            return 1.0
        return float(np.sqrt(max(1.0 + nl["epsilon"], 1e-6)))

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        worst = max(ev.by_flow, key=lambda k: float(k)) if ev.by_flow else None
        return f"the misfit grows with flow speed (fy MSE {ev.by_flow[worst]['fy_n']:.3g} at {worst} m/s)" if worst else ""

    def transform_motion(self, motion: LegMotion, nl: dict) -> LegMotion:  # noqa: D102
        if self.area is not None:
            return motion
        f = self.flow_factor(nl)
        return LegMotion(motion.dt_s, motion.theta_h_deg, motion.theta_k_deg, motion.omega_h_dps,
                         motion.omega_k_dps, motion.flow_speed_mps * f, motion.alpha_h_dps2, motion.alpha_k_dps2)


LIBRARY_RANK = 2  # place in the library's order (workbench.diagnose.library._in_tree)

EFFECTS = (TunnelBlockage,)
