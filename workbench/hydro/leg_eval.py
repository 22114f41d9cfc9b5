"""Leg-model evaluation inside the simulator: wrenches for a flow history, and the fixed-point map F.

The joint motion of a swim is fixed; only the flow each leg sees changes between fixed-point
iterations. :func:`leg_wrench_provider` is the one place the simulator asks a leg force model for
wrenches; :class:`FlowMap` is F = predict the wrenches, integrate the body, read the legs' new flow,
with the savings the schemes rely on (only the gaits still moving, only the ticks a window net sees).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from workbench.errors import ModelError
from workbench.hydro.body import (
    BodyState,
    integrate_stepwise,
    leg_flow_speeds,
    planar_coefficients,
    planar_sum,
)
from workbench.hydro.gait_batch import GaitBatch
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.motion import LegMotion
from workbench.hydro.robot import RobotSettings


def leg_wrench_provider(leg_model: LegForceModel, motion: LegMotion) -> Callable[[np.ndarray], np.ndarray]:
    """The one place the simulator gets leg wrenches: a function ``flow (N, T) -> wrench (N, T, 6)``.

    The joint motion is fixed during a simulation and only the flow changes between fixed-point
    iterations, so a model may offer ``flow_provider(motion)`` that does the flow-independent work
    once (the EF computes its kinematics once; a tabulated provider interpolates one cycle per
    leg over a grid of flow speeds). Any other :class:`LegForceModel` is called whole each time.
    """
    fast = getattr(leg_model, "flow_provider", None)
    inner = fast(motion) if callable(fast) else (
        lambda flow: leg_model.wrench(replace(motion, flow_speed_mps=flow)))
    # a provider marked ``partial`` computes some legs (rows) over some ticks on its own; others are sliced
    partial = bool(getattr(inner, "partial", False))
    name = getattr(leg_model, "name", "?")

    def provider(flow: np.ndarray, legs: np.ndarray | None = None, lo: int = 0, hi: int | None = None) -> np.ndarray:
        hi = motion.shape[1] if hi is None else hi
        whole = legs is None and lo == 0 and hi == motion.shape[1]
        n = motion.shape[0] if legs is None else len(legs)
        if whole or not partial:
            out = np.asarray(inner(flow), float)
            if not whole and out.shape == (*motion.shape, 6):
                out = out[:, lo:hi] if legs is None else out[legs, lo:hi]
        else:
            out = np.asarray(inner(flow, legs=legs, lo=lo, hi=hi), float)
        if out.shape != (n, hi - lo, 6):
            raise ModelError(f"leg model {name!r} returned shape {out.shape}, expected {(n, hi - lo, 6)}")
        if not np.all(np.isfinite(out)):
            raise ModelError(f"leg model {name!r} returned non-finite wrenches")
        return out

    return provider


class FlowMap:
    """The fixed-point map F the schemes share: leg wrenches, the body integration, the new flow.

    ``window_wrench`` and ``wrench`` predict the legs' wrenches for a flow history, ``swim``
    integrates the body under them and returns the state and the legs' new flow; ``calls`` counts
    the leg-model calls (a simulation's ``iterations``).
    """

    def __init__(self, gaits: GaitBatch, leg_model: LegForceModel, robot: RobotSettings, t: np.ndarray, dt_s: float):
        self.b, self.n = len(gaits), t.size
        self.robot, self.dt_s = robot, dt_s
        self.motion = gaits.leg_motion(t)
        self.provider = leg_wrench_provider(leg_model, self.motion)
        self.planar = planar_coefficients(robot)
        self.calls = 0
        #: leg-ticks predicted in the windows (what skipping frozen gaits and ticks saves)
        self.leg_evaluations = 0
        self.model = leg_model
        self.memory = memory_ticks(leg_model, dt_s)

    def window_wrench(self, flow: np.ndarray, lo: int, hi: int, gaits: np.ndarray | None = None,
                      prev: np.ndarray | None = None) -> np.ndarray:
        """(B, 4, hi - lo, 6) wrenches of ticks lo .. hi - 1, computed only for what can have changed.

        ``gaits`` (a (B,) mask) with ``prev`` (this window's wrenches from the last iteration): only
        those gaits are predicted again, the others' rows are taken from ``prev`` (a gait whose flow
        is frozen keeps its wrenches: every model is per leg, a leg's wrench depends on its own
        history only). A window net (``seq_len`` ticks at the simulation's tick, no fast path of its
        own) sees the current tick and the seq_len - 1 before it only, so it is run on ticks
        lo - memory .. hi (from 0 when that reaches the start): the same numbers at a fraction of
        the cost. A model with a fast path gets the tick range and the legs (see
        :func:`leg_wrench_provider`).
        """
        if gaits is None or prev is None:
            idx = np.arange(self.b)
        else:
            idx = np.nonzero(gaits)[0]
            if idx.size == 0:
                return prev
        prev = np.zeros((self.b, 4, hi - lo, 6)) if prev is None else prev
        legs = (4 * idx[:, None] + np.arange(4)[None, :]).ravel()
        self.calls += 1
        self.leg_evaluations += legs.size * (hi - lo)
        if self.memory is None:
            part = self.provider(flow.reshape(4 * self.b, self.n), None if idx.size == self.b else legs, lo, hi)
            part = part.reshape(idx.size, 4, hi - lo, 6)
        else:
            a = lo - self.memory if lo - self.memory > 0 else 0
            e = min(self.n, hi + 1)
            sub = legs if idx.size < self.b else slice(None)
            motion = replace(self.motion, flow_speed_mps=flow.reshape(4 * self.b, self.n)[sub, a:e],
                             **{f: getattr(self.motion, f)[sub, a:e] for f in _MOTION_SERIES
                                if getattr(self.motion, f) is not None})
            out = np.asarray(self.model.wrench(motion), float)
            if out.shape != (legs.size, e - a, 6) or not np.all(np.isfinite(out)):
                raise ModelError(f"leg model {getattr(self.model, 'name', '?')!r} returned shape {out.shape} or "
                                 f"non-finite wrenches for ticks {a}..{e}")
            part = out.reshape(idx.size, 4, e - a, 6)[:, :, lo - a:hi - a]
        if idx.size == self.b:
            return part
        prev[idx] = part                                # the last iteration's array (fresh from the model)
        return prev

    def wrench(self, flow: np.ndarray) -> np.ndarray:
        """(B, 4, T, 6) load-cell wrenches of all legs for a (B, 4, T) flow history."""
        self.calls += 1
        return self.provider(flow.reshape(4 * self.b, self.n)).reshape(self.b, 4, self.n, 6)

    def swim(self, w_leg: np.ndarray, lo: int = 0, hi: int | None = None,
             start: BodyState | None = None) -> tuple[dict, np.ndarray]:
        """Integrate ticks lo .. hi - 1 (from ``start``, the state at tick lo; rest at 0); state and new flow.

        ``w_leg`` holds the wrenches of the whole horizon, or of ticks lo .. hi - 1 only.
        """
        hi = self.n if hi is None else hi
        if w_leg.shape[2] != hi - lo:
            w_leg = w_leg[:, :, lo:hi]
        legs = np.ascontiguousarray(np.moveaxis(planar_sum(self.planar, w_leg), 1, 0))
        state = integrate_stepwise(self.robot, lambda k, v: legs[k], hi - lo, self.b, self.dt_s, start=start)
        return state, leg_flow_speeds(self.robot, state["vx"], state["vy"], state["r"])


_MOTION_SERIES = ("theta_h_deg", "theta_k_deg", "omega_h_dps", "omega_k_dps", "alpha_h_dps2", "alpha_k_dps2")


def memory_ticks(leg_model, dt_s: float) -> int | None:
    """Ticks of flow history a window net looks back (``seq_len`` at this tick), None when unknown or a fast path."""
    if callable(getattr(leg_model, "flow_provider", None)):
        return None
    seq, model_dt = getattr(leg_model, "seq_len", None), getattr(leg_model, "dt_s", None)
    if not isinstance(seq, int) or not isinstance(model_dt, float) or abs(model_dt - dt_s) > 0.02 * dt_s:
        return None
    return seq  # seq_len - 1 ticks back, plus one of margin
