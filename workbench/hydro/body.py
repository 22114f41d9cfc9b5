"""The robot's body in the plane: legs' wrenches about the metacenter, body drag, and the integrator.

The four legs' load-cell wrenches become one wrench about the metacenter (HAA rotation, mirror
image for right legs, p x F + R tau; paper equations 5-6); the body integrates surge, sway and yaw
in its own frame with added mass, body drag and cross-flow yaw damping, and the world position
follows through the yaw rotation. The flow each leg sees is its hip's velocity through still water.
Everything works on batches of gaits (B, ...) at once.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping

import numpy as np

from workbench.hydro.robot import RobotSettings


def planar_coefficients(robot: RobotSettings) -> np.ndarray:
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


def planar_sum(planar: np.ndarray, w_leg: np.ndarray) -> np.ndarray:
    """(B, T, 3): the four legs' body fx, fy, tz, summed left-right pairwise (exact for mirror images)."""
    k = np.ascontiguousarray(np.transpose(planar, (1, 2, 0)))  # (4, 6, 3)
    acc = w_leg[:, 0] @ k[0] + w_leg[:, 1] @ k[1]
    acc += w_leg[:, 2] @ k[2]
    acc += w_leg[:, 3] @ k[3]
    return acc


def legs_to_body(robot: RobotSettings, loadcell_wrench: np.ndarray) -> np.ndarray:
    """Load-cell wrenches ``(B, 4, T, 6)`` -> body-frame wrenches about the metacenter (same shape).

    F_mc = A F_leg and tau_mc = p x F_mc + A_tau tau_leg (paper equations 5-6), with A the HAA
    rotation (and mirror) of each leg and p its load-cell origin from the metacenter.
    """
    a_force, a_torque = robot.leg_rotations()
    f = np.einsum("lij,bltj->blti", a_force, loadcell_wrench[..., :3])
    tau = np.einsum("lij,bltj->blti", a_torque, loadcell_wrench[..., 3:])
    p = robot.hip_positions_m()[None, :, None, :]
    return np.concatenate([f, np.cross(np.broadcast_to(p, f.shape), f) + tau], axis=-1)


def leg_flow_speeds(robot: RobotSettings, vx: np.ndarray, vy: np.ndarray, r: np.ndarray) -> np.ndarray:
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

    def __init__(self, robot: RobotSettings):
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


def body_drag(robot: RobotSettings, vx, vy, r) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body drag (fx, fy, tz) of the robot at body-frame velocities (see :class:`BodyDrag`)."""
    return BodyDrag(robot)(vx, vy, r)


def integrate_body(robot: RobotSettings, leg_planar: np.ndarray, dt_s: float) -> dict[str, np.ndarray]:
    """Integrate the planar body motion from rest under the legs' force and yaw torque.

    ``leg_planar`` is (B, T, 3): the legs' summed fx, fy (N) and tz (N m) in the body frame.
    Returns (B, T) arrays x, y, yaw (world), vx, vy, r (body) and the body drag fx, fy, tz.
    """
    legs = np.ascontiguousarray(np.moveaxis(leg_planar, 1, 0))
    b, t = leg_planar.shape[:2]
    return integrate_stepwise(robot, lambda n, v: legs[n], t, b, dt_s)


def integrate_stepwise(robot: RobotSettings, leg_forces: Callable[[int, np.ndarray], np.ndarray], n_ticks: int,
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
