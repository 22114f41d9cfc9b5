"""Candidate effects of the fluid and of gravity on the leg (canonical names; docs/diagnose.md).

Each is a load the diagnosed model may lack, computed from the kinematics of
:mod:`workbench.diagnose.flowterms` and mapped to the load cell like the EF's own force
(along the web normal at Q, or along the links). All but the circulatory lag are linear in
their parameters.
"""

from __future__ import annotations

import numpy as np

from workbench.diagnose.flowterms import first_order_lag
from workbench.diagnose.library import ALL_CHANNELS, Context, Effect, SearchParam, Terms


class AddedMassError(Effect):
    """Extra added mass on the web normal: dF_n = -delta_kg a_n."""

    name = "added_mass_error"
    ranges = {"delta_kg": (-0.5, 0.5)}
    formula = "dF_n = -delta_kg * a_n (web normal, at Q)"

    def linear_names(self):  # noqa: D102
        return ["delta_kg"]

    def force_terms(self, ctx: Context, nl: dict) -> Terms:  # noqa: D102
        return Terms(["delta_kg"], [ctx.kin.added_mass_unit()], [ALL_CHANNELS])


class DragCoefficientError(Effect):
    """Extra normal drag: dF_n = 0.5 rho S delta_c |V_n| V_n."""

    name = "drag_coefficient_error"
    ranges = {"delta_c": (-3.0, 3.0)}
    formula = "dF_n = 0.5 rho S delta_c |V_n| V_n (web normal, at Q)"

    def linear_names(self):  # noqa: D102
        return ["delta_c"]

    def force_terms(self, ctx: Context, nl: dict) -> Terms:  # noqa: D102
        return Terms(["delta_c"], [ctx.kin.drag_unit()], [ALL_CHANNELS])


class Lift(Effect):
    """Lift from the tangential relative flow turned to the normal: dF_n = 0.5 rho S cl |V| V_t."""

    name = "lift"
    ranges = {"cl": (-3.0, 3.0)}
    formula = "dF_n = 0.5 rho S cl |V| V_t (web normal, at Q)"

    def linear_names(self):  # noqa: D102
        return ["cl"]

    def force_terms(self, ctx: Context, nl: dict) -> Terms:  # noqa: D102
        return Terms(["cl"], [ctx.kin.lift_unit()], [ALL_CHANNELS])


class LinkDrag(Effect):
    """Cross-flow drag of thigh (O-C) and calf (B to the web's near edge): 0.5 rho cd_d_m |V_n| V_n per length."""

    name = "link_drag"
    ranges = {"cd_d_m": (-0.1, 0.1)}
    formula = "dF/dl = 0.5 rho cd_d_m |V_n| V_n along thigh and calf"

    def __init__(self, x_m: float = 0.01, quadrature: int = 4):
        self.x_m = float(x_m)
        self.quadrature = int(quadrature)

    def linear_names(self):  # noqa: D102
        return ["cd_d_m"]

    def force_terms(self, ctx: Context, nl: dict) -> Terms:  # noqa: D102
        return Terms(["cd_d_m"], [ctx.kin.link_drag_unit(self.x_m, self.quadrature)], [ALL_CHANNELS])


class LegWeightBuoyancy(Effect):
    """A vertical load net_n (+ up) at arm_m from the hip along the hip-to-Q line.

    Linear in ``net_n`` and ``net_n * arm_m``; ``arm_m`` is their ratio (delta-method error).
    """

    name = "leg_weight_buoyancy"
    ranges = {"net_n": (-5.0, 5.0), "arm_m": (-0.1, 0.4)}
    formula = "fz += net_n; (tx, ty) += net_n arm_m (X_Q, -x_Q) / |Q|"

    def linear_names(self):  # noqa: D102
        return ["net_n", "net_arm_nm"]

    def force_terms(self, ctx: Context, nl: dict) -> Terms:  # noqa: D102
        force, moment = ctx.kin.point_load_units()
        sup_f = np.array([False, False, True, False, False, False])
        sup_m = np.array([False, False, False, True, True, False])
        return Terms(["net_n", "net_arm_nm"], [force, moment], [sup_f, sup_m])

    def canonical_params(self, coefs, nl, cov, local=None):  # noqa: D102
        net = coefs.get("net_n", 0.0)
        na = coefs.get("net_arm_nm", 0.0)
        arm = na / net if net else float("nan")
        v_net = cov.get(("net_n", "net_n"), np.nan)
        v_na = cov.get(("net_arm_nm", "net_arm_nm"), np.nan)
        c = cov.get(("net_n", "net_arm_nm"), 0.0)
        # delta method for arm = na / net
        v_arm = (v_na / net**2 + na**2 * v_net / net**4 - 2 * na * c / net**3) if net else np.nan
        return ({"net_n": net, "arm_m": arm},
                {"net_n": float(np.sqrt(max(v_net, 0))), "arm_m": float(np.sqrt(max(v_arm, 0)))})


class CirculatoryLag(Effect):
    """The circulatory (drag/normal) force through a first-order lag, tau = tau_chords c / max(|V_rel|, 0.05 m/s).

    The lagged force is the base drag 0.5 rho S c_r |V_n| V_n (the EF's own C_R by default);
    the term added is ``lag(F_D) - F_D`` along the normal at Q (coefficient one).
    """

    name = "circulatory_lag"
    ranges = {"tau_chords": (0.02, 30.0)}
    formula = "F_D -> first-order lag, tau = tau_chords c / max(|V_rel|, 0.05); c = 0.06 m"
    search = (SearchParam("tau_chords", (0.03, 0.1, 0.25, 0.5, 0.9, 1.5, 2.5, 4.0, 7.0, 12.0), (0.005, 40.0),
                          log=True),)

    def __init__(self, c_r: float = 0.7, chord_m: float = 0.06, speed_floor_mps: float = 0.05):
        self.c_r = float(c_r)
        self.chord_m = float(chord_m)
        self.floor = float(speed_floor_mps)

    def force_terms(self, ctx: Context, nl: dict) -> Terms:  # noqa: D102
        kin = ctx.kin
        f_d = kin.normal_drag_force(self.c_r)
        rate = np.maximum(kin.speed, self.floor) / (nl["tau_chords"] * self.chord_m)
        lagged = first_order_lag(f_d, rate, ctx.dt_s)
        return Terms(fixed=kin.normal_wrench(lagged - f_d))


FLUID_EFFECTS = (AddedMassError, DragCoefficientError, LinkDrag, Lift, LegWeightBuoyancy, CirculatoryLag)
