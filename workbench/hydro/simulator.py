"""Full-body swimming simulator (paper section III-E and IV-A): four legs, body drag, planar motion.

Each leg runs the paper's joint sinusoid (equation 3) with its own phase alpha. A leg force model
(any :class:`LegForceModel`: EF, FED-LSTM, augmented) predicts each leg's load-cell wrench from
its joint history and the flow it sees; :class:`RobotParams` turns that into a wrench about the
metacenter (HAA rotation by Rodrigues' formula, mirror image for right legs, p x F + R tau).
The body integrates surge, sway and yaw in its own frame with added mass, body drag and
cross-flow yaw damping, and the world position follows through the yaw rotation.

Leg force models take whole histories, while the flow each leg sees depends on the motion they
cause; :func:`simulate` therefore solves for the flow history by a relaxed fixed-point (Picard)
iteration: predict all 4B leg wrenches at once with the current flow history, integrate the
body, take the new flow history, repeat until it moves by less than ``tol_mps``. Everything is
vectorised over the batch of gaits, so a whole NSGA-II population steps together, and it is
deterministic (no randomness anywhere).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, Literal, Mapping, Sequence

import numpy as np

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.errors import ModelError, SettingError
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.motion import JointSinusoid, LegMotion
from workbench.hydro.robot import LEG_NAMES, RobotParams

#: the paper's fixed gait constants (section IV): theta_h_max, theta_k_min, phi
THETA_H_MAX_DEG = -100.0
THETA_K_MIN_DEG = 80.0
PHI_RAD = math.pi / 3
#: the tunnel's control tick (65 Hz); history-based leg models were trained on it
DEFAULT_DT_S = 1.0 / 65.0


@dataclass(frozen=True)
class GaitBatch:
    """B gaits for the four legs (LF, RF, LH, RH), the optimiser's parameters (paper table II).

    ``theta_h_min_deg`` and ``theta_k_max_deg`` are ``(B, 4)`` (the paper uses one value for all
    legs; per-leg values are allowed), ``frequency_hz`` is ``(B,)``, ``alpha_rad`` ``(B, 4)``.
    """

    theta_h_min_deg: np.ndarray
    theta_k_max_deg: np.ndarray
    frequency_hz: np.ndarray
    alpha_rad: np.ndarray
    theta_h_max_deg: float = THETA_H_MAX_DEG
    theta_k_min_deg: float = THETA_K_MIN_DEG
    phi_rad: float = PHI_RAD

    @classmethod
    def from_arrays(cls, theta_h_min_deg, theta_k_max_deg, frequency_hz, alpha_rad, **fixed) -> "GaitBatch":
        """Broadcast per-gait (B,) or per-leg (B, 4) values; scalars make a batch of one.

        Values that are not numbers, or shapes that do not broadcast, are a :class:`SettingError`.
        """
        def legs(x):
            x = np.asarray(x, float)
            if x.ndim <= 1:
                x = np.reshape(x, (-1, 1))
            return np.ascontiguousarray(np.broadcast_to(x, (b, 4)), dtype=float)

        try:
            alpha = np.atleast_2d(np.asarray(alpha_rad, float))
            b = max(alpha.shape[0], np.size(frequency_hz), np.atleast_1d(theta_h_min_deg).shape[0],
                    np.atleast_1d(theta_k_max_deg).shape[0])
            freq = np.ascontiguousarray(np.broadcast_to(np.asarray(frequency_hz, float).reshape(-1), (b,)))
            gaits = cls(legs(theta_h_min_deg), legs(theta_k_max_deg), freq, legs(alpha), **fixed)
        except (TypeError, ValueError) as exc:  # numpy's words for a string, a mapping or a ragged list
            raise SettingError(f"gait parameters must be numbers (one per gait, or four per gait for the "
                               f"legs): {exc}") from None
        if np.any(gaits.frequency_hz <= 0) or not all(np.all(np.isfinite(a)) for a in gaits._arrays()):
            raise SettingError("gait parameters must be finite with positive frequency")
        return gaits

    @classmethod
    def from_params(cls, params: Sequence[Mapping], labels: Sequence[str] | None = None, **fixed) -> "GaitBatch":
        """From gait-file ``params`` dicts (data contract section 5).

        A missing or bad value is a :class:`SettingError`; with ``labels`` (one per gait) its ``where``
        names the first gait at fault, so a caller can add the file: ``exc.located(path=...)``.
        """
        try:
            return cls._from_params(params, **fixed)
        except SettingError as exc:
            if labels is None:
                raise
            for label, p in zip(labels, params, strict=True):
                try:
                    cls._from_params([p], **fixed)
                except SettingError as one:
                    raise one.located(where=label) from None
            raise exc.located(where=", ".join(labels)) from None

    @classmethod
    def _from_params(cls, params: Sequence[Mapping], **fixed) -> "GaitBatch":
        try:
            return cls.from_arrays(
                [p["theta_h_min_deg"] for p in params], [p["theta_k_max_deg"] for p in params],
                [p["frequency_hz"] for p in params],
                [p["alpha_rad"] if np.ndim(p["alpha_rad"]) else [p["alpha_rad"]] * 4 for p in params], **fixed)
        except KeyError as exc:
            raise SettingError(f"gait parameters lack {exc}") from None
        except TypeError:  # a list or a number where the params table should be
            raise SettingError("gait parameters must be a table of theta_h_min_deg, theta_k_max_deg, "
                               "frequency_hz and alpha_rad") from None

    def _arrays(self):
        return (self.theta_h_min_deg, self.theta_k_max_deg, self.frequency_hz, self.alpha_rad)

    def __len__(self) -> int:
        return int(self.frequency_hz.shape[0])

    def rows(self, idx) -> "GaitBatch":
        """A sub-batch (index, slice or mask)."""
        idx = np.atleast_1d(np.arange(len(self))[idx])
        return replace(self, theta_h_min_deg=self.theta_h_min_deg[idx], theta_k_max_deg=self.theta_k_max_deg[idx],
                       frequency_hz=self.frequency_hz[idx], alpha_rad=self.alpha_rad[idx])

    def mirrored(self) -> "GaitBatch":
        """The mirror-image gaits: left and right legs swap their parameters."""
        swap = [1, 0, 3, 2]
        return replace(self, theta_h_min_deg=self.theta_h_min_deg[:, swap],
                       theta_k_max_deg=self.theta_k_max_deg[:, swap], alpha_rad=self.alpha_rad[:, swap])

    def sinusoid(self) -> JointSinusoid:
        """The paper's equation 3 with array parameters broadcasting to (B, 4, T)."""
        return JointSinusoid(self.theta_h_min_deg[..., None], self.theta_h_max_deg, self.theta_k_min_deg,
                             self.theta_k_max_deg[..., None], self.frequency_hz[:, None, None], self.phi_rad,
                             self.alpha_rad[..., None])

    def leg_motion(self, t_s: np.ndarray) -> LegMotion:
        """All 4B legs' joint histories (rows ordered gait-major: b * 4 + leg), analytic rates, no flow."""
        t = np.asarray(t_s, float)
        th, tk, wh, wk, ah, ak = (np.broadcast_to(x, (len(self), 4, t.size)).reshape(4 * len(self), t.size)
                                  for x in self.sinusoid().evaluate(t))
        dt = float(t[1] - t[0]) if t.size > 1 else 1.0
        return LegMotion(dt, th, tk, wh, wk, np.zeros_like(th), ah, ak)

    def to_params(self) -> list[dict]:
        """Gait-file ``params`` dicts (contract names; scalars where all legs agree)."""
        out = []
        for i in range(len(self)):
            row = {}
            for name, arr in (("theta_h_min_deg", self.theta_h_min_deg), ("theta_k_max_deg", self.theta_k_max_deg)):
                vals = arr[i]
                row[name] = float(vals[0]) if np.all(vals == vals[0]) else [float(v) for v in vals]
            row["frequency_hz"] = float(self.frequency_hz[i])
            row["alpha_rad"] = [float(a) for a in self.alpha_rad[i]]
            out.append(row)
        return out


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


# -- the pieces of one Picard iteration ---------------------------------------------------------
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


def _planar_coefficients(robot: RobotParams) -> np.ndarray:
    """(3, 4, 6): body fx, fy, tz about the metacenter as linear maps of each leg's load-cell wrench."""
    a_force, a_torque = robot.leg_rotations()
    p = robot.hip_positions_m()
    k = np.zeros((3, 4, 6))
    k[0, :, :3] = a_force[:, 0, :]
    k[1, :, :3] = a_force[:, 1, :]
    # tz = p_x F_y - p_y F_x + (A_tau tau)_z with F = A f
    k[2, :, :3] = p[:, 0, None] * a_force[:, 1, :] - p[:, 1, None] * a_force[:, 0, :]
    k[2, :, 3:] = a_torque[:, 2, :]
    return k


def _planar_sum(planar: np.ndarray, w_leg: np.ndarray) -> np.ndarray:
    """(B, T, 3): the four legs' body fx, fy, tz, summed left-right pairwise (exact for mirror images)."""
    k = np.ascontiguousarray(np.transpose(planar, (1, 2, 0)))  # (4, 6, 3)
    acc = w_leg[:, 0] @ k[0] + w_leg[:, 1] @ k[1]
    acc += w_leg[:, 2] @ k[2]
    acc += w_leg[:, 3] @ k[3]
    return acc


def legs_to_body(robot: RobotParams, loadcell_wrench: np.ndarray) -> np.ndarray:
    """Load-cell wrenches ``(B, 4, T, 6)`` -> body-frame wrenches about the metacenter (same shape).

    F_mc = A F_leg and tau_mc = p x F_mc + A_tau tau_leg (paper equations 5-6), with A the HAA
    rotation (and mirror) of each leg and p its load-cell origin from the metacenter.
    """
    a_force, a_torque = robot.leg_rotations()
    f = np.einsum("lij,bltj->blti", a_force, loadcell_wrench[..., :3])
    tau = np.einsum("lij,bltj->blti", a_torque, loadcell_wrench[..., 3:])
    p = robot.hip_positions_m()[None, :, None, :]
    return np.concatenate([f, np.cross(np.broadcast_to(p, f.shape), f) + tau], axis=-1)


def leg_flow_speeds(robot: RobotParams, vx: np.ndarray, vy: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Flow speed each leg sees, ``(B, 4, T)``: its hip's velocity through still water along its +y.

    A leg at hip h moves with v + omega x h; the tunnel's flow along the load cell's -y at speed U
    is the same relative flow as the leg swimming along its +y at U. Cross-flow components are
    not seen by the leg models (they were measured in axial flow only).
    """
    h = robot.hip_positions_m()
    fwd = robot.leg_forward_axes()
    vx, vy, r = (np.asarray(a)[:, None, :] for a in (vx, vy, r))
    ux = vx - r * h[None, :, 1, None]
    uy = vy + r * h[None, :, 0, None]
    return ux * fwd[None, :, 0, None] + uy * fwd[None, :, 1, None]


class BodyDrag:
    """Body drag (fx, fy, tz) from body-frame velocities, with its constants prepared once.

    Surge: the forward law at vy. Sway and yaw: the lateral law spread evenly over the body length
    (cross-flow strips at Gauss-Legendre stations): a strip at station s moves sideways at
    vx - r s, so yaw rotation meets lateral drag and is damped (the paper has no yaw damping;
    without it any yaw torque spins the robot up for ever). At r = 0 the strips sum to the
    lateral law at vx exactly. ``extra_yaw_damping_nms`` adds a linear term.

    It runs once per tick for the whole batch, so it is written as two small matrix products:
    velocities (B, 3) -> the speed of each drag element (B, 1 + n) -> drag -> (fx, fy, tz).
    """

    def __init__(self, robot: RobotParams):
        n = robot.strip_stations if robot.body_length_m > 0 else 1
        x, w = np.polynomial.legendre.leggauss(n)
        s = robot.body_length_m / 2 * x
        w = w / 2  # strip weights sum to one: the strips share the lateral law
        self.stations_m = s
        # element speeds: column 0 is the surge element, columns 1.. the lateral strips
        self._p = np.zeros((3, 1 + n))
        self._p[1, 0] = 1.0
        self._p[0, 1:] = 1.0
        self._p[2, 1:] = -s
        fwd, lat = _law_terms(robot.forward_drag), _law_terms(robot.lateral_drag)
        self._c2, self._c1, self._c0, self._v0, self._slope = (
            np.array([f] + [lt] * n) for f, lt in zip(fwd, lat, strict=True))
        self._linear = bool(np.any(self._v0 > 0))
        # element forces -> (fx, fy, tz); a strip's force f (along x) at station s gives tz = -s f
        self._w = np.zeros((1 + n, 3))
        self._w[0, 1] = 1.0
        self._w[1:, 0] = w
        self._w[1:, 2] = -w * s
        self._damp = robot.extra_yaw_damping_nms

    def planar(self, v: np.ndarray) -> np.ndarray:
        """Drag (B, 3) = (fx, fy, tz) for body velocities ``v`` (B, 3) = (vx, vy, r)."""
        if v.shape[0] == 1:
            # numpy's product of a single row takes another kernel (a vector-matrix product) whose last bits
            # differ: a gait swum alone (a worker's part, the last gait still iterating) must get the numbers
            # it gets in company (docs/gaits.md "Workers"), so one row goes through as two
            return self.planar(np.concatenate([v, v]))[:1]
        u = v @ self._p
        speed = np.abs(u)
        mag = (self._c2 * speed + self._c1) * speed + self._c0
        if self._linear:
            mag = np.where(speed < self._v0, self._slope * speed, mag)
        out = (np.sign(u) * np.maximum(mag, 0.0)) @ self._w
        out = -out
        if self._damp:
            out[:, 2] -= self._damp * v[:, 2]
        return out

    def __call__(self, vx, vy, r) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """fx, fy (N) and tz (N m) for velocity arrays of one shape."""
        vx, vy, r = np.broadcast_arrays(*(np.asarray(a, float) for a in (vx, vy, r)))
        f = self.planar(np.stack([vx.ravel(), vy.ravel(), r.ravel()], axis=-1))
        return tuple(f[:, k].reshape(vx.shape) for k in range(3))


def _law_terms(law) -> tuple[float, float, float, float, float]:
    """(c2, c1, c0, v0, slope below v0) of a DragLaw; v0 = 0 when the polynomial runs down to rest."""
    c2, c1, c0 = law.coefficients
    if law.below_range == "drop_intercept":
        c0 = 0.0
    v0 = law.speed_range_mps[0] if law.below_range == "linear_to_zero" and law.speed_range_mps[0] > 0 else 0.0
    slope = float(law.polynomial(v0)) / v0 if v0 > 0 else 0.0
    return c2, c1, c0, v0, slope


def body_drag(robot: RobotParams, vx, vy, r) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body drag (fx, fy, tz) of the robot at body-frame velocities (see :class:`BodyDrag`)."""
    return BodyDrag(robot)(vx, vy, r)


def integrate_body(robot: RobotParams, leg_planar: np.ndarray, dt_s: float) -> dict[str, np.ndarray]:
    """Integrate the planar body motion from rest under the legs' force and yaw torque.

    ``leg_planar`` is (B, T, 3): the legs' summed fx, fy (N) and tz (N m) in the body frame.
    Returns (B, T) arrays x, y, yaw (world), vx, vy, r (body) and the body drag fx, fy, tz.
    """
    legs = np.ascontiguousarray(np.moveaxis(leg_planar, 1, 0))
    b, t = leg_planar.shape[:2]
    return integrate_stepwise(robot, lambda n, v: legs[n], t, b, dt_s)


def integrate_stepwise(robot: RobotParams, leg_forces: Callable[[int, np.ndarray], np.ndarray], n_ticks: int,
                       batch: int, dt_s: float, *, start: "BodyState | None" = None) -> dict[str, np.ndarray]:
    """The integrator itself, asking the legs' (B, 3) = (fx, fy, tz) tick by tick: ``leg_forces(n, v)``.

    ``v`` is the (B, 3) body velocity (vx, vy, r) at tick n. Body-frame equations with added mass
    (Kirchhoff): m_x dvx/dt = Fx + m_y r vy, m_y dvy/dt = Fy - m_x r vx,
    I dr/dt = tz + (m_x - m_y) vx vy (Munk moment, optional), where F and tz sum the legs and the
    body drag at tick n. Semi-implicit Euler: the velocities step with the forces at tick n, then
    yaw and the world position step with the new velocities (rotated by the mid-step yaw).
    Passing a callable lets an instantaneous leg model be stepped directly (the tests check the
    fixed-point solution against that).

    ``start`` continues from a :class:`BodyState` (the state at some tick s of an earlier
    integration) instead of rest; the returned arrays then hold ticks s .. s + n_ticks - 1 and
    ``leg_forces`` is still asked with the local index 0, 1, ...  Continuing gives bit-identical
    numbers to integrating the whole span at once (the windowed solver relies on it).
    """
    b, t = batch, n_ticks
    mx, my, iz = robot.mass_x_kg, robot.mass_y_kg, robot.inertia_z_kgm2
    munk = (mx - my) if robot.munk_moment else 0.0
    # Coriolis and Munk terms as (B, 3) = coef * v[:, i] * v[:, j]
    first, second = [1, 0, 0], [2, 2, 1]
    coef = np.array([my, -mx, munk])
    step = dt_s / np.array([mx, my, iz])
    drag = BodyDrag(robot)
    vel = np.zeros((t, b, 3))
    pose = np.zeros((t, b, 3))
    body = np.zeros((t, b, 3))
    if start is None:
        v = np.zeros((b, 3))
        x = np.zeros(b)
        y = np.zeros(b)
        yaw = np.zeros(b)
    else:
        v, x, y, yaw = (np.array(a, float) for a in (start.v, start.x, start.y, start.yaw))
        vel[0] = v
        pose[0, :, 0], pose[0, :, 1], pose[0, :, 2] = x, y, yaw
    half = 0.5 * dt_s
    for n in range(t):
        f = drag.planar(v)
        body[n] = f
        if n == t - 1:
            break
        f += leg_forces(n, v)
        f += coef * v[:, first] * v[:, second]
        v = v + step * f
        r = v[:, 2]
        mid = yaw + half * r
        yaw = yaw + dt_s * r
        c, s = np.cos(mid), np.sin(mid)
        x = x + dt_s * (c * v[:, 0] - s * v[:, 1])
        y = y + dt_s * (s * v[:, 0] + c * v[:, 1])
        vel[n + 1] = v
        pose[n + 1, :, 0], pose[n + 1, :, 1], pose[n + 1, :, 2] = x, y, yaw
    out = {}
    for arr, names in ((pose, ("x", "y", "yaw")), (vel, ("vx", "vy", "r")), (body, ("fx", "fy", "tz"))):
        for k, name in enumerate(names):
            out[name] = np.ascontiguousarray(arr[:, :, k].T)
    return out


@dataclass(frozen=True)
class BodyState:
    """The body's state at one tick, (B,) or (B, 3) arrays: what a continued integration starts from."""

    v: np.ndarray
    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray

    @classmethod
    def at(cls, state: Mapping[str, np.ndarray], n: int) -> "BodyState":
        """The state at local tick ``n`` of an :func:`integrate_stepwise` result."""
        return cls(np.stack([state["vx"][:, n], state["vy"][:, n], state["r"][:, n]], axis=-1),
                   state["x"][:, n].copy(), state["y"][:, n].copy(), state["yaw"][:, n].copy())


# -- the simulation ------------------------------------------------------------------------------
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


class _Solve:
    """The pieces the fixed-point schemes share: leg wrenches, the body integration, the new flow."""

    def __init__(self, gaits: GaitBatch, leg_model: LegForceModel, robot: RobotParams, t: np.ndarray, dt_s: float):
        self.b, self.n = len(gaits), t.size
        self.robot, self.dt_s = robot, dt_s
        self.motion = gaits.leg_motion(t)
        self.provider = leg_wrench_provider(leg_model, self.motion)
        self.planar = _planar_coefficients(robot)
        self.calls = 0
        #: leg-ticks predicted in the windows (what skipping frozen gaits and ticks saves)
        self.leg_evaluations = 0
        self.model = leg_model
        self.memory = _memory_ticks(leg_model, dt_s)

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
        legs = np.ascontiguousarray(np.moveaxis(_planar_sum(self.planar, w_leg), 1, 0))
        state = integrate_stepwise(self.robot, lambda k, v: legs[k], hi - lo, self.b, self.dt_s, start=start)
        return state, leg_flow_speeds(self.robot, state["vx"], state["vy"], state["r"])


_MOTION_SERIES = ("theta_h_deg", "theta_k_deg", "omega_h_dps", "omega_k_dps", "alpha_h_dps2", "alpha_k_dps2")


def _memory_ticks(leg_model, dt_s: float) -> int | None:
    """Ticks of flow history a window net looks back (``seq_len`` at this tick), None when unknown or a fast path."""
    if callable(getattr(leg_model, "flow_provider", None)):
        return None
    seq, model_dt = getattr(leg_model, "seq_len", None), getattr(leg_model, "dt_s", None)
    if not isinstance(seq, int) or not isinstance(model_dt, float) or abs(model_dt - dt_s) > 0.02 * dt_s:
        return None
    return seq  # seq_len - 1 ticks back, plus one of margin


def _periodic_guess(flow: np.ndarray, lo: int, hi: int, period_ticks: np.ndarray) -> None:
    """Fill ticks lo .. hi - 1 of ``flow`` (B, 4, T) with its own last gait cycle (in place).

    The legs' flow repeats with the gait once the swim settles, so flow(t) = flow(t - period) is a
    good first guess for a new stretch of the horizon; before one cycle is known, the last value is held.
    """
    if hi <= lo or lo == 0:
        return
    n = np.arange(lo, hi)
    for i, p in enumerate(period_ticks):
        src = n - p
        while np.any(src >= lo):  # windows longer than a cycle: reach back whole cycles
            src = np.where(src >= lo, src - p, src)
        if src.min() < 0:
            flow[i, :, lo:hi] = flow[i, :, lo - 1:lo]
            continue
        k = np.floor(src).astype(int)
        frac = src - k
        row = flow[i]
        row[:, lo:hi] = row[:, k] * (1 - frac) + row[:, np.minimum(k + 1, lo - 1)] * frac


def simulate(gaits: GaitBatch, leg_model: LegForceModel, robot: RobotParams, *, duration_s: float = 20.0,
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
    if duration_s <= 0 or dt_s <= 0:
        raise SettingError("duration_s and dt_s must be positive")
    if not 0 < relaxation <= 1:
        raise SettingError("relaxation must be in (0, 1]")
    if method not in METHODS:
        raise SettingError(f"method must be one of {METHODS}, got {method!r}")
    if window_s <= 0 or max_window_s <= 0 or max_iter < 1:
        raise SettingError("window_s and max_window_s must be positive and max_iter at least 1")
    b = len(gaits)
    n_ticks = int(round(duration_s / dt_s)) + 1
    t = np.arange(n_ticks) * dt_s
    solve = _Solve(gaits, leg_model, robot, t, dt_s)
    flow = np.zeros((b, 4, n_ticks))
    guessed = initial_flow is not None
    if guessed:
        initial_flow = np.asarray(initial_flow, float)
        if initial_flow.shape != flow.shape or not np.all(np.isfinite(initial_flow)):
            raise SettingError(f"initial_flow must be finite with shape {flow.shape}, got {initial_flow.shape}")
        flow[:] = initial_flow
        flow[:, :, 0] = 0.0                            # the swim starts at rest
    failed = np.zeros(b, bool)
    if method == "picard":
        w_leg, state, residual, k = _picard(solve, flow, tol_mps, max_iter, relaxation, on_iteration)
    else:
        # gaits that a window gave up are solved again from still water on windows four times shorter
        # (the others held); whether a gait is retried depends on that gait alone, not on the batch
        todo = np.ones(b, bool)
        attempt = 0
        while True:
            trial = flow.copy() if attempt == 0 else np.where(todo[:, None, None], 0.0, flow)
            gave_up = ~todo
            scale = 4.0 ** attempt
            _windowed(solve, trial, gaits, tol_mps, max_iter, relaxation, window_s / scale,
                      max(max_window_s / scale, window_s / scale), gave_up, on_iteration, anderson,
                      guessed=guessed and attempt == 0)
            flow[todo] = trial[todo]
            todo &= gave_up
            attempt += 1
            if not todo.any() or window_s / 4.0 ** attempt < MIN_WINDOW_S:
                break
        failed = todo
        # the honest check: one pass over the whole horizon with the flow found
        w_leg = solve.wrench(flow)
        state, new_flow = solve.swim(w_leg)
        residual = np.abs(new_flow - flow).max(axis=(1, 2))
        if on_iteration is not None:
            on_iteration(solve.calls, residual.copy())
        k = solve.calls
    w_body = legs_to_body(robot, w_leg)
    zeros = np.zeros_like(state["fx"])
    body = np.stack([state["fx"], state["fy"], zeros, zeros, zeros, state["tz"]], axis=-1)
    return Trajectory(t_s=t, x_m=state["x"], y_m=state["y"], yaw_rad=state["yaw"], vx_mps=state["vx"],
                      vy_mps=state["vy"], yaw_rate_rps=state["r"], leg_wrench=w_body, body_wrench=body,
                      leg_flow_mps=flow, gaits=gaits, model=getattr(leg_model, "name", "model"), iterations=k,
                      residual_mps=residual, converged=(residual < tol_mps) & ~failed)


def _picard(solve: _Solve, flow, tol_mps, max_iter, relaxation, on_iteration):
    """Whole-horizon relaxed Picard iteration (the earlier scheme); updates ``flow`` in place."""
    b = solve.b
    active = np.ones(b, bool)
    residual = np.full(b, np.inf)
    for k in range(1, max_iter + 1):
        w_leg = solve.wrench(flow)
        state, new_flow = solve.swim(w_leg)
        change = np.abs(new_flow - flow).max(axis=(1, 2))
        residual = np.where(active, change, residual)
        if on_iteration is not None:
            on_iteration(k, residual.copy())
        done = active & (change < tol_mps)
        active &= ~done
        if not active.any():
            break
        flow[:] = np.where(active[:, None, None], flow + relaxation * (new_flow - flow), flow)
    return w_leg, state, residual, k


#: no leg of a swimming robot sees a flow this fast (m/s); an iterate beyond it is diverging
FLOW_LIMIT_MPS = 5.0
#: the shortest window a retry uses (s)
MIN_WINDOW_S = 0.5
#: ticks at a window's end that are solved again with the next window (a leg model's one-tick look-ahead)
OVERLAP_TICKS = 2


def window_schedule(n_ticks: int, dt_s: float, window_s: float, max_window_s: float) -> list[tuple[int, int]]:
    """The windows (lo, hi) of ticks: ``window_s`` long, doubling up to ``max_window_s``, overlapping by 2 ticks.

    The schedule depends on the settings and the horizon only, never on the batch, so a gait's
    result does not depend on the other gaits it is simulated with.
    """
    width = max(OVERLAP_TICKS + 2, int(round(window_s / dt_s)))
    cap = max(width, int(round(max_window_s / dt_s)))
    out, lo = [], 0
    while True:
        hi = min(n_ticks, lo + width)
        out.append((lo, hi))
        if hi >= n_ticks:
            return out
        lo = hi - OVERLAP_TICKS
        width = min(2 * width, cap)


class _Anderson:
    """Anderson acceleration (type II, per gait) of the relaxed fixed-point step on a window's flow.

    With the last m iterates x_i and residuals f_i = F(x_i) - x_i, the step is
    w f - sum_i gamma_i (dx_i + w df_i), gamma minimising |f - sum gamma_i df_i| (least squares,
    lightly regularised). A gait whose residual grew restarts its history.
    """

    def __init__(self, b: int, depth: int):
        self.depth = depth
        self.dx: list[np.ndarray] = []
        self.df: list[np.ndarray] = []
        self.prev: tuple[np.ndarray, np.ndarray] | None = None

    def step(self, x: np.ndarray, f: np.ndarray, omega: np.ndarray, restart: np.ndarray) -> np.ndarray:
        if self.prev is not None:
            self.dx.append(x - self.prev[0])
            self.df.append(f - self.prev[1])
            if len(self.dx) > self.depth:
                self.dx.pop(0)
                self.df.pop(0)
        self.prev = (x.copy(), f.copy())
        w = omega[:, None]
        if not self.dx:
            return w * f
        dx, df = np.stack(self.dx, 1), np.stack(self.df, 1)          # (B, m, n)
        gram = df @ np.swapaxes(df, 1, 2)                             # (B, m, m)
        scale = np.trace(gram, axis1=1, axis2=2)[:, None, None] / gram.shape[1] + 1e-300
        gram = gram + 1e-10 * scale * np.eye(gram.shape[1])
        gamma = np.linalg.solve(gram, (df @ f[:, :, None]))[..., 0]    # (B, m)
        gamma = np.where(restart[:, None], 0.0, gamma)
        if restart.any():
            for arr in (*self.dx, *self.df):
                arr[restart] = 0.0
        return w * f - np.einsum("bm,bmn->bn", gamma, dx + w[:, None] * df)


def _windowed(solve: _Solve, flow, gaits: GaitBatch, tol_mps, max_iter, relaxation, window_s, max_window_s,
              failed, on_iteration, anderson: int = 0, guessed: bool = False) -> None:
    """Waveform relaxation on growing windows (see :func:`simulate`); updates ``flow`` and ``failed`` in place."""
    b, n_ticks, dt = solve.b, solve.n, solve.dt_s
    period = 1.0 / (gaits.frequency_hz * dt)           # ticks per gait cycle (not an integer)
    start = None                                        # the state at the window's first tick
    filled = n_ticks if guessed else 1                  # ticks with a first guess so far
    windows = window_schedule(n_ticks, dt, window_s, max_window_s)
    for j, (lo, hi) in enumerate(windows):
        guess_to = min(n_ticks, hi + OVERLAP_TICKS)
        if guess_to > filled:
            _periodic_guess(flow, filled, guess_to, period)
            filled = guess_to
        omega = np.full(b, relaxation)
        last = np.full(b, np.inf)
        active = ~failed
        state = None
        # this window's wrenches: frozen gaits keep theirs; gaits held or given up are not predicted (zero)
        w_win = np.zeros((b, 4, hi - lo, 6))
        acc = _Anderson(b, anderson) if anderson else None
        for _ in range(max_iter):
            w_win = solve.window_wrench(flow, lo, hi, active, w_win)
            state, new = solve.swim(w_win, lo, hi, start)
            x = flow[:, :, lo:hi]
            change = np.abs(new - x).max(axis=(1, 2))
            # a diverging gait (non-finite, or flows no swimmer sees) is given up before it poisons the batch
            wild = active & ~(np.abs(new).max(axis=(1, 2)) < FLOW_LIMIT_MPS)
            if wild.any():
                failed |= wild
                active &= ~wild
                change = np.where(wild, np.inf, change)
            if on_iteration is not None:
                on_iteration(solve.calls, np.where(active | wild, change, 0.0))
            grew = active & (change > last)
            omega = np.where(grew, np.maximum(0.5 * omega, 0.05), omega)
            last = np.where(active, change, last)
            active &= ~(change < tol_mps)
            if not active.any():
                break
            f = np.where(active[:, None, None], new - x, 0.0)
            step = omega[:, None, None] * f
            if acc is not None:
                step = acc.step(x.reshape(b, -1), f.reshape(b, -1), omega, grew).reshape(x.shape)
            nxt = x + step
            # an accelerated step that leaves the physical range falls back to the relaxed one
            wild_step = ~(np.abs(nxt).max(axis=(1, 2)) < FLOW_LIMIT_MPS)
            nxt = np.where(wild_step[:, None, None], x + omega[:, None, None] * f, nxt)
            flow[:, :, lo:hi] = np.where(active[:, None, None], nxt, x)
        failed |= active                               # not converged in its window: flagged, not iterated further
        if j + 1 < len(windows):
            start = BodyState.at(state, windows[j + 1][0] - lo)
