"""Maskell's blockage correction as a prior for ``tunnel_blockage`` (issue 13, item 4).

Maskell (1963, ARC R&M 3400) corrects a bluff body's dynamic pressure in a closed test section
for wake blockage: ``q_c / q = 1 + theta C_D S / C``, with ``S`` the body's frontal area, ``C``
the test section's cross-section, ``C_D`` the drag coefficient on ``S`` and ``theta`` about
2.5-2.8 for flat plates. In the effect's terms (``U_eff = U sqrt(1 + epsilon)``, so
``q_eff / q = 1 + epsilon``) Maskell's value is ``epsilon = theta C_D S / C``.

The leg's frontal area moves with the stroke. Assumptions (stated in docs/diagnose.md):

* only the web blocks the flow (the links are thin rods, a few per cent of its area);
* the web is a flat plate of area ``S_web`` (``web_side_m``^2); its frontal area at an instant is
  its projection on the plane normal to the stream, ``S_web |n_X|`` (``n`` the web normal in
  the leg plane, the stream along -X);
* a run's blockage follows its time-averaged frontal area over the analysed ticks (the wake
  responds to the mean drag area, not to each instant): ``S_run = S_web mean |n_X|``;
* ``C_D`` is that of a plate normal to the stream (1.17 for a square plate, Hoerner), applied to
  the projected area.

Each run gets its own prior value ``epsilon_run``; the effect fits one factor on all of them,
``epsilon_run (1 + d_maskell)``, with a Gaussian prior ``d_maskell ~ N(0, width^2)`` (width 0.5
by default: Maskell's theta and the plate's C_D are each uncertain by 10-20 %, and the stroke's
mean frontal area stands for an unsteady wake).
"""

from __future__ import annotations

import numpy as np

#: Maskell's theta for flat plates (2.5-2.8) and the drag coefficient of a square plate normal to the flow
THETA = 2.5
C_D = 1.17


def frontal_area(ctx) -> np.ndarray:
    """Per run (B,): the web's time-averaged frontal area (m^2) over its analysed (else valid) ticks."""
    n_x = np.abs(ctx.kin.state.normal[..., 0])                          # (B, T)
    mask = getattr(ctx.rs, "fit", None)
    if mask is None or not np.any(mask):
        mask = getattr(ctx.rs, "valid", np.ones(n_x.shape, bool))
    mask = np.asarray(mask, bool)
    num = np.where(mask, n_x, 0.0).sum(axis=1)
    den = np.maximum(mask.sum(axis=1), 1)
    return ctx.kin.area_m2 * num / den


def prior_epsilon(ctx, area_m2: float, theta: float = THETA, c_d: float = C_D) -> np.ndarray:
    """Per run (B,): Maskell's ``epsilon = theta C_D S / C`` (zero for runs without flow)."""
    eps = theta * c_d * frontal_area(ctx) / area_m2
    return np.where(run_flow(ctx) > 0, eps, 0.0)


def run_flow(ctx) -> np.ndarray:
    """Per run (B,): the flow speed's magnitude (the batch's, else the largest in the motion)."""
    flow = getattr(ctx.rs, "flow", None)
    if flow is not None:
        return np.abs(np.asarray(flow, float))
    u = np.abs(np.asarray(ctx.motion.flow_speed_mps, float))
    return u.reshape(u.shape[0], -1).max(axis=1) if u.ndim else np.full(ctx.motion.shape[0], float(u))


def wrench_at_factors(ctx, factors: np.ndarray) -> np.ndarray:
    """The model's wrench with each run's flow speed scaled by its own factor (B,)."""
    from workbench.hydro.motion import LegMotion

    m = ctx.motion
    u = np.asarray(m.flow_speed_mps, float)
    f = np.asarray(factors, float).reshape((-1,) + (1,) * (u.ndim - 1))
    scaled = LegMotion(m.dt_s, m.theta_h_deg, m.theta_k_deg, m.omega_h_dps, m.omega_k_dps, u * f,
                       m.alpha_h_dps2, m.alpha_k_dps2)
    return np.asarray(ctx.model.wrench(scaled), float)


def blockage_terms(ctx, eps_run: np.ndarray, h: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """(fixed, column) of the blockage at each run's prior value, per unit of ``d_maskell``.

    ``fixed = M(U sqrt(1 + eps_run)) - M(U)``; the column is ``eps_run dM/d(epsilon)`` there (a
    centred difference of half-width ``h`` in epsilon), so ``epsilon_run (1 + d)`` is the fitted
    blockage to first order in ``d eps_run``.
    """
    e = np.asarray(eps_run, float)
    base = ctx.base
    at = wrench_at_factors(ctx, np.sqrt(1.0 + e))
    up = wrench_at_factors(ctx, np.sqrt(np.maximum(1.0 + e + h, 1e-6)))
    dn = wrench_at_factors(ctx, np.sqrt(np.maximum(1.0 + e - h, 1e-6)))
    col = (up - dn) / (2 * h) * e[:, None, None]
    return at - base, col


def data_alone(d: float, var_post: float, width: float) -> tuple[float, float] | None:
    """What the data alone say of ``d`` (value, standard error), undoing the Gaussian prior N(0, width^2).

    Exact for one parameter; with correlated parameters it reads the marginal only.
    """
    if not (np.isfinite(d) and np.isfinite(var_post)) or var_post <= 0:
        return None
    prec = 1.0 / var_post - 1.0 / width ** 2
    if prec <= 1e-12:
        return None                       # the data add (next to) nothing to the prior
    return float(d / var_post / prec), float(np.sqrt(1.0 / prec))
