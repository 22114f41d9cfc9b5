"""The servo between command and leg: a dead time then a first-order lag (``servo_lag``; docs/diagnose.md).

It acts on what the leg is commanded to do, so it is part of the physical leg handed to the simulator.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from workbench.diagnose.effects.base import Effect, SearchParam
from workbench.diagnose.evidence import ccf_clause
from workbench.hydro.motion import LegMotion


def lag_filter(x: np.ndarray, tau_s: float, dt_s: float, axis: int = -1) -> np.ndarray:
    """First-order low-pass (time constant ``tau_s``) along ``axis``, starting at rest on the first sample.

    Exact for an input that is linear between samples (first-order hold), so the 65 Hz control
    ticks follow the continuous lag closely.
    """
    if tau_s <= 0:
        return np.array(x, float)
    e = np.exp(-dt_s / tau_s)
    g = tau_s * (1 - e) / dt_s
    b, a = np.array([1 - g, g - e]), np.array([1.0, -e])
    x = np.asarray(x, float)
    ax = axis % x.ndim
    x0 = np.take(x, [0], axis=ax)
    zi = signal.lfilter_zi(b, a).reshape([-1 if i == ax else 1 for i in range(x.ndim)]) * x0
    y, _ = signal.lfilter(b, a, x, axis=ax, zi=zi)
    return y


def dead_time(x: np.ndarray, delay_s: float, dt_s: float, axis: int = -1) -> np.ndarray:
    """``x`` delayed by ``delay_s`` along ``axis`` (4-point Lagrange fractional delay; the first sample held before).

    Accurate to about 1e-3 of the amplitude at 6 Hz on 65 Hz ticks (a linear interpolation loses
    several per cent there).
    """
    x = np.asarray(x, float)
    if delay_s <= 0:
        return np.array(x, float)
    d = delay_s / dt_s
    k = int(np.floor(d))
    u = 1.0 - (d - k)                      # the target lies u ticks after sample n - k - 1
    w = (-u * (u - 1) * (u - 2) / 6, (u + 1) * (u - 1) * (u - 2) / 2, -(u + 1) * u * (u - 2) / 2,
         (u + 1) * u * (u - 1) / 6)
    n = x.shape[axis]
    idx = np.arange(n) - k - 1
    out = np.zeros_like(x)
    for j, wj in zip((-1, 0, 1, 2), w, strict=True):
        out += wj * np.take(x, np.clip(idx + j, 0, n - 1), axis=axis)
    return out


class ServoLag(Effect):
    """Actual joint angles = the commanded angles after a dead time and a first-order lag, both joints.

    Searched as the effective delay ``tau_s`` (dead time plus lag: the phase every harmonic sees
    at low frequency) and the share of it that is dead time. A pure first-order lag of a 60 ms
    dead time attenuates a stroke's 6 Hz harmonics to 40 %, and the force effects then take the
    misfit; a dead time with a lag fits a servo of any mix. ``shapes`` (option): ``lag`` (only a
    first-order lag, the share fixed at 0) or ``dead+lag`` (default).
    """

    name = "servo_lag"
    ranges = {"tau_s": (0.0, 0.3)}
    stage = "input"
    formula = "theta = theta_cmd(t - dead_s) / (1 + lag_s s), both joints; tau_s = dead_s + lag_s"
    TAU = SearchParam("tau_s", (0.005, 0.012, 0.02, 0.03, 0.04, 0.055, 0.075, 0.1, 0.14, 0.2), (0.0005, 0.4), log=True)
    SHARE = SearchParam("dead_share", (0.0, 0.5, 1.0), (0.0, 1.0))
    search = (TAU, SHARE)
    surrogate_ok = True
    lookahead = True
    #: the split of tau_s between dead time and lag locates the servo's shape, it does not measure its size
    location_params = ("dead_share", "dead_s", "lag_s")

    def __init__(self, shapes: str = "dead+lag"):
        if shapes not in ("lag", "dead+lag"):
            from workbench.errors import ModelError

            raise ModelError(f"servo_lag: shapes must be 'lag' or 'dead+lag', not {shapes!r}")
        self.shapes = shapes
        self.search = (self.TAU, self.SHARE) if shapes == "dead+lag" else (self.TAU,)

    def options(self) -> dict:  # noqa: D102
        return {"shapes": self.shapes}

    @staticmethod
    def split(nl: dict) -> tuple[float, float]:
        """(dead time, lag) in seconds from the searched values (a saved ``{"tau_s": x}`` is a pure lag)."""
        tau = float(nl["tau_s"])
        share = float(np.clip(nl.get("dead_share", 0.0), 0.0, 1.0))
        return tau * share, tau * (1.0 - share)

    def canonical_params(self, coefs, nl, cov, local=None):  # noqa: D102
        params, se = super().canonical_params(coefs, nl, cov, local)
        if "tau_s" in nl:
            params["dead_s"], params["lag_s"] = self.split(nl)
        return params, se

    def on_output(self, w: np.ndarray, dt_s: float, nl: dict) -> np.ndarray:
        """A causal model's output through the same dead time and lag (first order in tau)."""
        dead, lag = self.split(nl)
        return lag_filter(dead_time(w, dead, dt_s, axis=-2), lag, dt_s, axis=-2)

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        return ccf_clause(ev, "model_force_rate", "the rate of the model's force")

    def transform_motion(self, motion: LegMotion, nl: dict) -> LegMotion:  # noqa: D102
        dead, tau = self.split(nl)
        dt = motion.dt_s
        if tau <= 0 and dead <= 0:
            return motion
        # angles, rates and accelerations through the same (linear) delay and lag: the lag of a
        # derivative is the derivative of the lag, and filtering each keeps the 65 Hz error at 1e-4
        ah, ak = motion.accelerations_dps2()
        f = (lambda a: lag_filter(dead_time(a, dead, dt), tau, dt))  # noqa: E731
        return LegMotion(dt, f(motion.theta_h_deg), f(motion.theta_k_deg), f(motion.omega_h_dps),
                         f(motion.omega_k_dps), motion.flow_speed_mps, f(ah), f(ak))


LIBRARY_RANK = 1  # place in the library's order (workbench.diagnose.library._in_tree)

EFFECTS = (ServoLag,)
