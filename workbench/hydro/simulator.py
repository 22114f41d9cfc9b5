"""Full-body swimming simulator (paper section III-E and IV-A): four legs, body drag, planar motion.

Each leg runs the paper's joint sinusoid (equation 3) with its own phase alpha. A leg force model
(any :class:`LegForceModel`: EF, FED-LSTM, augmented) predicts each leg's load-cell wrench from
its joint history and the flow it sees; :class:`RobotSettings` turns that into a wrench about the
metacenter (HAA rotation by Rodrigues' formula, mirror image for right legs, p x F + R tau).
The body integrates surge, sway and yaw in its own frame with added mass, body drag and
cross-flow yaw damping, and the world position follows through the yaw rotation.

Leg force models take whole histories, while the flow each leg sees depends on the motion they
cause; :func:`simulate` therefore solves for the flow history by a relaxed fixed-point (Picard)
iteration: predict all 4B leg wrenches at once with the current flow history, integrate the
body, take the new flow history, repeat until it moves by less than ``tol_mps``. Everything is
vectorised over the batch of gaits, so a whole NSGA-II population steps together, and it is
deterministic (no randomness anywhere).

This module holds :func:`simulate`, its settings and its result (:class:`Trajectory`); the parts
live beside it, one concern each, and the names callers use are importable from here too:
``gait_batch`` (:class:`GaitBatch`, the paper's fixed gait constants), ``body`` (legs to body,
body drag, the integrator), ``leg_eval`` (leg-model evaluation and the fixed-point map F) and
``fixed_point`` (the windowed and Picard schemes).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Literal, Mapping, Sequence

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.errors import SettingError
from workbench.hydro.body import (
    BodyDrag,
    BodyState,
    body_drag,
    integrate_body,
    integrate_stepwise,
    leg_flow_speeds,
    legs_to_body,
)
from workbench.hydro.fixed_point import (
    FLOW_LIMIT_MPS,
    MIN_WINDOW_S,
    OVERLAP_TICKS,
    picard,
    window_schedule,
    windowed,
)
from workbench.hydro.gait_batch import PHI_RAD, THETA_H_MAX_DEG, THETA_K_MIN_DEG, GaitBatch
from workbench.hydro.leg_eval import FlowMap, leg_wrench_provider
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.robot import LEG_NAMES, RobotSettings

#: the names callers import from here (the simulator's parts live in gait_batch, body, leg_eval, fixed_point)
__all__ = [
    "BodyDrag", "BodyState", "DEFAULT_DT_S", "FLOW_LIMIT_MPS", "GaitBatch", "METHODS", "MIN_WINDOW_S",
    "OVERLAP_TICKS", "PHI_RAD", "SIM_SETTINGS", "THETA_H_MAX_DEG", "THETA_K_MIN_DEG", "SimulationSettings",
    "Trajectory", "body_drag", "integrate_body", "integrate_stepwise", "leg_flow_speeds", "leg_wrench_provider",
    "legs_to_body", "simulate", "simulation_settings", "window_schedule",
]

#: the tunnel's control tick (65 Hz); history-based leg models were trained on it
DEFAULT_DT_S = 1.0 / 65.0


@dataclass(frozen=True)
class Trajectory:
    """Simulated swims of a gait batch; arrays are (B, T) unless noted, tick 0 is the start at rest.

    World frame: origin at the start, +y along the initial heading, +x to its right (the trial
    frame of data contract section 2); yaw is counter-clockwise seen from above (positive turns
    left). Body velocities are in the body frame (vx right, vy forward). Wrenches are in the body
    frame about the metacenter, channels in contract order (fx, fy, fz, tx, ty, tz).
    """

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    yaw_rad: np.ndarray
    vx_mps: np.ndarray
    vy_mps: np.ndarray
    yaw_rate_rps: np.ndarray
    #: (B, 4, T, 6) each leg's wrench, legs in LEG_NAMES order
    leg_wrench: np.ndarray
    #: (B, T, 6) body drag and yaw damping
    body_wrench: np.ndarray
    #: (B, 4, T) flow speed each leg saw (m/s, along its load cell's -y)
    leg_flow_mps: np.ndarray
    gaits: GaitBatch
    model: str
    iterations: int
    #: (B,) last change of the flow history (m/s) and whether it fell below the tolerance
    residual_mps: np.ndarray
    converged: np.ndarray

    @property
    def total_wrench(self) -> np.ndarray:
        """(B, T, 6) legs plus body."""
        return self.leg_wrench.sum(axis=1) + self.body_wrench

    @property
    def leg_thrust_n(self) -> np.ndarray:
        """(B, T) the four legs' summed force along the body's forward axis."""
        return self.leg_wrench[..., 1].sum(axis=1)

    def __len__(self) -> int:
        return int(self.x_m.shape[0])

    def to_frame(self, labels: Sequence[Mapping] | None = None):
        """Long polars frame: one row per gait and tick (``gait`` index, optional label columns)."""
        import polars as pl

        b, t = self.x_m.shape
        cols: dict[str, np.ndarray] = {
            "gait": np.repeat(np.arange(b), t), "time_s": np.tile(self.t_s, b),
            "x_m": self.x_m.ravel(), "y_m": self.y_m.ravel(), "yaw_rad": self.yaw_rad.ravel(),
            "vx_mps": self.vx_mps.ravel(), "vy_mps": self.vy_mps.ravel(), "yaw_rate_rps": self.yaw_rate_rps.ravel(),
        }
        total = self.total_wrench
        for k, ch in enumerate(WRENCH_CHANNELS):
            cols[ch] = total[..., k].ravel()
        for k, ch in enumerate(WRENCH_CHANNELS):
            cols[f"body_{ch}"] = self.body_wrench[..., k].ravel()
        for j, leg in enumerate(LEG_NAMES):
            cols[f"{leg.lower()}_flow_mps"] = self.leg_flow_mps[:, j].ravel()
            for k, ch in enumerate(WRENCH_CHANNELS):
                cols[f"{leg.lower()}_{ch}"] = self.leg_wrench[:, j, :, k].ravel()
        frame = pl.DataFrame(cols)
        if labels is not None:
            extra = {key: np.repeat(np.asarray([lab[key] for lab in labels]), t) for key in labels[0]}
            frame = pl.DataFrame(extra).hstack(frame)
        return frame


#: fixed-point schemes: ``windowed`` (default) or the whole-horizon ``picard`` iteration (kept for comparison)
METHODS = ("windowed", "picard")


@dataclass(frozen=True)
class SimulationSettings:
    """The ``simulation`` section of pipelines/robot.yaml; a key left out (None) keeps :func:`simulate`'s default."""

    duration_s: float | None = None
    dt_s: float | None = None
    tol_mps: float | None = None
    max_iter: int | None = None
    relaxation: float | None = None
    method: Literal["windowed", "picard"] | None = None
    window_s: float | None = None
    max_window_s: float | None = None
    anderson: int | None = None


#: the ``simulation`` section of pipelines/robot.yaml: keyword arguments of :func:`simulate`
SIM_SETTINGS = tuple(SimulationSettings.__dataclass_fields__)


def simulation_settings(doc: Mapping | None, *, path=None, key: str = "simulation") -> dict:
    """Keyword arguments for :func:`simulate` from a parameter-file section (only the keys it gives).

    Built by :func:`workbench.params.build`: an unknown key, a wrong type or an unknown method is a
    ParamsError naming ``path`` and ``simulation.<key>`` with the allowed keys or choices.
    """
    from workbench.params import build

    settings = build(SimulationSettings, doc, key=key, path=path)
    return {k: v for k, v in settings.__dict__.items() if v is not None}


def simulate(gaits: GaitBatch, leg_model: LegForceModel, robot: RobotSettings, *, duration_s: float = 20.0,
             dt_s: float = DEFAULT_DT_S, tol_mps: float = 1e-5, max_iter: int = 40, relaxation: float = 1.0,
             method: str = "windowed", window_s: float = 20.0, max_window_s: float = 60.0,
             anderson: int = 5, initial_flow: np.ndarray | None = None,
             on_iteration: Callable[[int, np.ndarray], None] | None = None) -> Trajectory:
    """Simulate every gait of the batch from rest for ``duration_s``; returns the :class:`Trajectory`.

    The flow each leg sees depends on the motion the legs cause, and a leg model takes whole
    histories, so the flow history of all 4B legs is a fixed point: flow = F(flow), F = predict the
    wrenches, integrate the body, read the legs' flow. F is causal (the flow at tick n depends on
    earlier flow only; a model's one-tick look-ahead, e.g. a centred difference, is fine). The
    default ``method="windowed"`` solves it window by window (waveform relaxation):

    1. on a window of ``window_s`` (the body integrated from the converged state at the window's
       start), iterate the relaxed step flow + w (F(flow) - flow), accelerated by Anderson mixing
       of the last ``anderson`` iterates (0: plain relaxation), per gait, until no leg's flow in the
       window moves by ``tol_mps``; w starts at ``relaxation`` and halves for a gait whose change
       grows;
    2. freeze the window, extend the flow by one gait cycle (periodic guess) and go on with a
       window twice as long, up to ``max_window_s``;
    3. a gait still moving after ``max_iter`` iterations in a window is solved again, from still
       water with the others held, on windows four times shorter (down to 0.5 s);
    4. finally one pass of F over the whole horizon: ``residual_mps`` is its largest change of any
       leg's flow (the honest fixed-point residual) and ``converged`` says it is below
       ``tol_mps``. An unconverged gait is a flagged result, never a silent one.

    ``initial_flow`` (B, 4, T), e.g. the flow of a cheaper model's swim of the same gaits, replaces
    the still-water start and the periodic guesses (the direct check of tabulated gaits starts from
    the tabulated flow and needs a few iterations instead of tens).

    The schedule depends on the settings and the gait only, so a gait's result does not depend on
    the rest of the batch; everything is deterministic. ``method="picard"`` is the earlier
    whole-horizon relaxed iteration (``max_iter`` in all), which leaves gaits unconverged at 60 s
    (docs/hydro.md has the measurements). ``iterations`` counts the leg-model calls;
    ``on_iteration(calls, change_per_gait)`` reports progress.
    """
    _check_settings(duration_s, dt_s, relaxation, method, window_s, max_window_s, max_iter)
    n_ticks = int(round(duration_s / dt_s)) + 1
    t = np.arange(n_ticks) * dt_s
    solve = FlowMap(gaits, leg_model, robot, t, dt_s)
    flow = _start_flow(len(gaits), n_ticks, initial_flow)
    failed = np.zeros(len(gaits), bool)
    if method == "picard":
        w_leg, state, residual, k = picard(solve, flow, tol_mps, max_iter, relaxation, on_iteration)
    else:
        failed = _solve_windows(solve, flow, gaits, tol_mps, max_iter, relaxation, window_s, max_window_s,
                                anderson, on_iteration, guessed=initial_flow is not None)
        w_leg, state, residual, k = _final_pass(solve, flow, on_iteration)
    w_body = legs_to_body(robot, w_leg)
    zeros = np.zeros_like(state["fx"])
    body = np.stack([state["fx"], state["fy"], zeros, zeros, zeros, state["tz"]], axis=-1)
    return Trajectory(t_s=t, x_m=state["x"], y_m=state["y"], yaw_rad=state["yaw"], vx_mps=state["vx"],
                      vy_mps=state["vy"], yaw_rate_rps=state["r"], leg_wrench=w_body, body_wrench=body,
                      leg_flow_mps=flow, gaits=gaits, model=getattr(leg_model, "name", "model"), iterations=k,
                      residual_mps=residual, converged=(residual < tol_mps) & ~failed)


def _check_settings(duration_s: float, dt_s: float, relaxation: float, method: str, window_s: float,
                    max_window_s: float, max_iter: int) -> None:
    """Refuse settings :func:`simulate` cannot run with (a ``SettingError`` naming the setting)."""
    if duration_s <= 0 or dt_s <= 0:
        raise SettingError("duration_s and dt_s must be positive")
    if not 0 < relaxation <= 1:
        raise SettingError("relaxation must be in (0, 1]")
    if method not in METHODS:
        raise SettingError(f"method must be one of {METHODS}, got {method!r}")
    if window_s <= 0 or max_window_s <= 0 or max_iter < 1:
        raise SettingError("window_s and max_window_s must be positive and max_iter at least 1")


def _start_flow(b: int, n_ticks: int, initial_flow: np.ndarray | None) -> np.ndarray:
    """The (B, 4, T) flow to start from: still water, or ``initial_flow`` (checked) with the swim at rest at tick 0."""
    flow = np.zeros((b, 4, n_ticks))
    if initial_flow is not None:
        initial_flow = np.asarray(initial_flow, float)
        if initial_flow.shape != flow.shape or not np.all(np.isfinite(initial_flow)):
            raise SettingError(f"initial_flow must be finite with shape {flow.shape}, got {initial_flow.shape}")
        flow[:] = initial_flow
        flow[:, :, 0] = 0.0                            # the swim starts at rest
    return flow


def _solve_windows(solve: FlowMap, flow: np.ndarray, gaits: GaitBatch, tol_mps: float, max_iter: int,
                   relaxation: float, window_s: float, max_window_s: float, anderson: int,
                   on_iteration: Callable[[int, np.ndarray], None] | None, *, guessed: bool) -> np.ndarray:
    """Solve ``flow`` in place window by window, retrying given-up gaits on shorter windows; the gaits still failed.

    Gaits that a window gave up are solved again from still water on windows four times shorter
    (the others held); whether a gait is retried depends on that gait alone, not on the batch.
    """
    todo = np.ones(len(gaits), bool)
    attempt = 0
    while True:
        trial = flow.copy() if attempt == 0 else np.where(todo[:, None, None], 0.0, flow)
        gave_up = ~todo
        scale = 4.0 ** attempt
        windowed(solve, trial, gaits, tol_mps, max_iter, relaxation, window_s / scale,
                 max(max_window_s / scale, window_s / scale), gave_up, on_iteration, anderson,
                 guessed=guessed and attempt == 0)
        flow[todo] = trial[todo]
        todo &= gave_up
        attempt += 1
        if not todo.any() or window_s / 4.0 ** attempt < MIN_WINDOW_S:
            return todo


def _final_pass(solve: FlowMap, flow: np.ndarray, on_iteration: Callable[[int, np.ndarray], None] | None):
    """The honest check: one pass of F over the whole horizon; ``(leg wrenches, state, residual, calls)``."""
    w_leg = solve.wrench(flow)
    state, new_flow = solve.swim(w_leg)
    residual = np.abs(new_flow - flow).max(axis=(1, 2))
    if on_iteration is not None:
        on_iteration(solve.calls, residual.copy())
    return w_leg, state, residual, solve.calls
