"""Kinematic regressors of the candidate effects: web normal terms, link drag, point loads.

Everything is computed from a :class:`~workbench.hydro.motion.LegMotion` with the conventions
of :mod:`workbench.hydro.kinematics` (leg plane X forward = load-cell y, Y up = load-cell z;
the tunnel water moves along -X at the flow speed). Each method returns the load-cell wrench
``(B, T, 6)`` of a *unit* parameter, so that an effect's contribution is ``param * column``.
"""

from __future__ import annotations

from functools import cached_property

import numpy as np

from workbench.hydro.kinematics import DEFAULT_GEOMETRY, LegGeometry, leg_state
from workbench.hydro.motion import LegMotion

RHO_KGPM3 = 1000.0


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1]


def _perp(v: np.ndarray) -> np.ndarray:
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def add_point_force(out: np.ndarray, force2: np.ndarray, point2: np.ndarray, x_m: float) -> np.ndarray:
    """Add a leg-plane force (..., 2) at a leg-plane point (..., 2), ``x_m`` off the hip axis, to a wrench.

    The same numbers as :func:`workbench.hydro.ef.force_at_point_to_wrench` (r x F with
    r = (x_m, X, Y), F = (0, F_X, F_Y)), accumulated in place without building 3-vectors: the
    link terms sum eight Gauss points and are recomputed whenever the motion changes.
    """
    fx_, fy_ = force2[..., 0], force2[..., 1]
    out[..., 1] += fx_
    out[..., 2] += fy_
    out[..., 3] += point2[..., 0] * fy_ - point2[..., 1] * fx_
    out[..., 4] -= x_m * fy_
    out[..., 5] += x_m * fx_
    return out


class LegKinematics:
    """Web and link kinematics of one motion batch, with the unit wrenches of the candidate terms."""

    def __init__(self, motion: LegMotion, geometry: LegGeometry = DEFAULT_GEOMETRY, rho_kgpm3: float = RHO_KGPM3):
        self.motion = motion
        self.geometry = geometry
        self.rho = rho_kgpm3
        ah, ak = motion.accelerations_dps2()
        self.wh = np.radians(motion.omega_h_dps)
        self.wk = np.radians(motion.omega_k_dps)
        self.ah = np.radians(ah)
        self.ak = np.radians(ak)
        self.state = leg_state(np.radians(motion.theta_h_deg), np.radians(motion.theta_k_deg), self.wh, self.wk,
                               self.ah, self.ak, geometry)
        u = np.asarray(motion.flow_speed_mps, float)
        self.water = np.stack([-u, np.zeros_like(u)], axis=-1)
        self._units: dict[tuple, np.ndarray] = {}

    def _memo(self, key: tuple, make) -> np.ndarray:
        """Unit columns are asked for again and again while the motion stays the same."""
        if key not in self._units:
            self._units[key] = make()
        return self._units[key]

    @property
    def area_m2(self) -> float:
        """Web area S."""
        return self.geometry.web_side_m ** 2

    @cached_property
    def rel(self) -> np.ndarray:
        """Water velocity relative to Q (B, T, 2)."""
        return self.water - self.state.q_vel

    @cached_property
    def v_n(self) -> np.ndarray:
        """Normal component of the relative water velocity at Q."""
        return _dot(self.rel, self.state.normal)

    @cached_property
    def v_t(self) -> np.ndarray:
        """Tangential component of the relative water velocity at Q."""
        return _dot(self.rel, self.state.tangent)

    @cached_property
    def speed(self) -> np.ndarray:
        """|V_rel| at Q."""
        return np.hypot(self.rel[..., 0], self.rel[..., 1])

    @cached_property
    def a_n(self) -> np.ndarray:
        """Normal component of Q's acceleration."""
        return _dot(self.state.q_acc, self.state.normal)

    @cached_property
    def water_acc(self) -> np.ndarray:
        """The water's acceleration (B, T, 2): -dU/dt along X (zero in a steady tunnel)."""
        u = np.asarray(self.motion.flow_speed_mps, float)
        du = np.zeros_like(u)
        if u.shape[1] > 2 and np.ptp(u, axis=1).max() > 0:
            du = np.gradient(u, self.motion.dt_s, axis=1, edge_order=2)
        return np.stack([-du, np.zeros_like(du)], axis=-1)

    @cached_property
    def rel_acc_n(self) -> np.ndarray:
        """Normal component of Q's acceleration relative to the water."""
        return _dot(self.state.q_acc - self.water_acc, self.state.normal)

    @cached_property
    def omega_v_t(self) -> np.ndarray:
        """The rotating-plate part of d/dt(v_n): web rate times the tangential relative velocity.

        With ``n = -(-sin psi, cos psi)`` the normal turns as ``dn/dt = -omega t``, so
        ``d/dt((v_Q - u) . n) = (a_Q - du/dt) . n + omega ((u - v_Q) . t) = rel_acc_n + omega v_t``.
        """
        return self.state.web_rate * self.v_t

    @cached_property
    def web_acc(self) -> np.ndarray:
        """The web's angular acceleration (rad/s^2)."""
        return self.ah + self.ak

    @cached_property
    def kc(self) -> np.ndarray:
        """Keulegan-Carpenter number per run (B, 1): KC = 2 pi A / L, A half the diagonal of Q's path box.

        The box of Q's path does not change when a run is padded with its edge poses, so KC is
        a property of the run, not of the batch it sits in.
        """
        q = self.state.q
        amp = 0.5 * np.hypot(np.ptp(q[..., 0], axis=1), np.ptp(q[..., 1], axis=1))[:, None]
        return 2 * np.pi * amp / self.geometry.web_side_m

    def normal_wrench(self, f_n: np.ndarray) -> np.ndarray:
        """A force ``f_n`` along the web normal at Q as a load-cell wrench."""
        st = self.state
        return add_point_force(np.zeros(f_n.shape + (6,)), f_n[..., None] * st.normal, st.q,
                               self.geometry.web_offset_x_m)

    def couple_wrench(self, m_x: np.ndarray) -> np.ndarray:
        """A pure in-plane couple (about the load cell's +x, the leg plane's normal) as a wrench."""
        out = np.zeros(m_x.shape + (6,))
        out[..., 3] = m_x
        return out

    def normal_law(self, quadrature: int = 5) -> tuple[np.ndarray, np.ndarray]:
        """Post-stall normal-force law of the rotating web per unit coefficient: (force at Q, couple about Q).

        Strip theory over the chord: ``f(s) = 0.5 rho L |V(s)| V_n(s)`` per unit chord with
        ``V(s) = V_Q - omega s n`` (the web turns at omega about Q), i.e. ``C_N = C_N90 sin(alpha)``
        locally; integrated with Gauss points, which also gives the centre of pressure's couple.
        """
        def make():
            side = self.geometry.web_side_m
            n = self.state.normal
            xs, ws = np.polynomial.legendre.leggauss(quadrature)
            f = np.zeros(n.shape[:-1])
            m = np.zeros(n.shape[:-1])
            for x, w in zip(xs * side / 2, ws * side / 2, strict=True):
                rel = self.rel - (self.state.web_rate * x)[..., None] * n
                fs = 0.5 * self.rho * side * np.hypot(rel[..., 0], rel[..., 1]) * _dot(rel, n)
                f += w * fs
                m += w * x * fs
            return np.stack([f, m], axis=-1)

        fm = self._memo(("nlaw", quadrature), make)
        return fm[..., 0], fm[..., 1]

    def normal_law_wrench(self, f: np.ndarray, m: np.ndarray) -> np.ndarray:
        """A normal force at Q with its couple (from :meth:`normal_law`) as a wrench."""
        return self.normal_wrench(f) + self.couple_wrench(m)

    # --------------------------------------------------------------- unit columns
    def added_mass_unit(self) -> np.ndarray:
        """dF_n = -a_n (per kg of extra added mass)."""
        return self._memo(("am",), lambda: self.normal_wrench(-self.a_n))

    def normal_drag_force(self, c: float = 1.0) -> np.ndarray:
        """0.5 rho S c |V_n| V_n (N along the normal)."""
        return 0.5 * self.rho * self.area_m2 * c * np.abs(self.v_n) * self.v_n

    def drag_unit(self) -> np.ndarray:
        """dF_n = 0.5 rho S |V_n| V_n (per unit of drag coefficient)."""
        return self._memo(("drag",), lambda: self.normal_wrench(self.normal_drag_force(1.0)))

    def lift_unit(self) -> np.ndarray:
        """dF_n = 0.5 rho S |V| V_t (per unit lift coefficient), the tangential flow turned to the normal."""
        return self._memo(("lift",), lambda: self.normal_wrench(0.5 * self.rho * self.area_m2 * self.speed * self.v_t))

    def link_points(self, quadrature: int = 4):
        """Gauss points of thigh (O to C) and calf (B to the web's near edge): position, velocity, normal, length."""
        g, st = self.geometry, self.state
        xs, ws = np.polynomial.legendre.leggauss(quadrature)
        s01, w01 = (xs + 1) / 2, ws / 2
        c_vel = self.wh[..., None] * _perp(st.c)
        a_vel = (self.wh + self.wk)[..., None] * _perp(st.a)
        thigh_normal = _perp(st.c / g.oc_m)
        for s, w in zip(s01, w01, strict=False):
            yield s * st.c, s * c_vel, thigh_normal, w * g.oc_m
        # the calf's points are C + kappa A: B at kappa = 1, the web's near edge at kappa_end
        calf_len = g.bq_over_bc * g.bc_m - g.web_side_m / 2
        kappa_end = 1.0 - calf_len / g.oa_m
        for s, w in zip(s01, w01, strict=False):
            kap = 1.0 + s * (kappa_end - 1.0)
            yield st.c + kap * st.a, c_vel + kap * a_vel, st.normal, w * calf_len

    def link_drag_unit(self, x_m: float = 0.01, quadrature: int = 4) -> np.ndarray:
        """Cross-flow drag of thigh and calf per unit cd_d_m: 0.5 rho |V_n| V_n per length, integrated."""
        return self._memo(("link", x_m, quadrature), lambda: self._link_drag(x_m, quadrature))

    def _link_drag(self, x_m: float, quadrature: int) -> np.ndarray:
        out = np.zeros(self.state.q.shape[:-1] + (6,))
        for pos, vel, nrm, dl in self.link_points(quadrature):
            v_n = _dot(self.water - vel, nrm)
            f = (0.5 * self.rho * np.abs(v_n) * v_n * dl)[..., None] * nrm
            add_point_force(out, f, pos, x_m)
        return out

    def link_inertia_units(self, x_m: float = 0.01, quadrature: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit wrenches of the links' inertia: (added mass per length, thigh mass, calf mass).

        Added mass (kg/m) acts on each point's acceleration relative to the water along the
        link's normal; a link's structural mass (kg, spread evenly along it) on the point's whole
        acceleration. Each is ``-m a`` at the Gauss points, ``x_m`` off the hip axis.
        """
        return self._memo(("linkinertia", x_m, quadrature), lambda: self._link_inertia(x_m, quadrature))

    def link_accelerations(self, quadrature: int = 4):
        """Gauss points of thigh and calf with their accelerations: (position, acceleration, normal, dl, link)."""
        g, st = self.geometry, self.state
        c_acc = self.ah[..., None] * _perp(st.c) - (self.wh ** 2)[..., None] * st.c
        wpsi, apsi = self.wh + self.wk, self.ah + self.ak
        a_acc = apsi[..., None] * _perp(st.a) - (wpsi ** 2)[..., None] * st.a
        points = list(self.link_points(quadrature))
        xs, _ = np.polynomial.legendre.leggauss(quadrature)
        s01 = (xs + 1) / 2
        calf_len = g.bq_over_bc * g.bc_m - g.web_side_m / 2
        kappa_end = 1.0 - calf_len / g.oa_m
        for i, (pos, _vel, nrm, dl) in enumerate(points):
            if i < quadrature:
                yield pos, s01[i] * c_acc, nrm, dl, "thigh"
            else:
                kap = 1.0 + s01[i - quadrature] * (kappa_end - 1.0)
                yield pos, c_acc + kap * a_acc, nrm, dl, "calf"

    def link_lengths(self) -> dict[str, float]:
        """Wetted lengths of thigh (O-C) and calf (B to the web's near edge)."""
        g = self.geometry
        return {"thigh": g.oc_m, "calf": g.bq_over_bc * g.bc_m - g.web_side_m / 2}

    def _link_inertia(self, x_m: float, quadrature: int):
        shape = self.state.q.shape[:-1] + (6,)
        added, thigh, calf = np.zeros(shape), np.zeros(shape), np.zeros(shape)
        lengths = self.link_lengths()
        for pos, acc, nrm, dl, link in self.link_accelerations(quadrature):
            a_n = _dot(acc - self.water_acc, nrm)
            add_point_force(added, -(a_n * dl)[..., None] * nrm, pos, x_m)
            add_point_force(thigh if link == "thigh" else calf, -acc * (dl / lengths[link]), pos, x_m)
        return added, thigh, calf

    def spread_weight_units(self, x_m: float = 0.01, quadrature: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Unit wrenches of a vertical net load (+ up, weight minus buoyancy, per N): (thigh, calf, web).

        Thigh and calf loads are spread evenly along them (Gauss points ``x_m`` off the hip
        axis); the web's acts at Q (``web_offset_x_m`` off the axis).
        """
        def make():
            shape = self.state.q.shape[:-1]
            lengths = self.link_lengths()
            out = {"thigh": np.zeros(shape + (6,)), "calf": np.zeros(shape + (6,))}
            up = np.zeros(shape + (2,))
            up[..., 1] = 1.0
            for pos, _acc, _nrm, dl, link in self.link_accelerations(quadrature):
                add_point_force(out[link], up * (dl / lengths[link]), pos, x_m)
            web = add_point_force(np.zeros(shape + (6,)), up, self.state.q, self.geometry.web_offset_x_m)
            return np.stack([out["thigh"], out["calf"], web])

        return tuple(self._memo(("spreadweight", x_m, quadrature), make))

    def point_load_units(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit wrenches of a vertical load: (per N of net_n at the hip, per N m of net_n * arm_m).

        The load acts at ``arm_m`` from the hip along the 3-D hip-to-Q line, so its moment is
        ``net_n * arm_m * (X_Q, -x_Q) / |Q|`` on (tx, ty).
        """
        q = self.state.q
        x = self.geometry.web_offset_x_m
        norm = np.sqrt(x * x + q[..., 0] ** 2 + q[..., 1] ** 2)
        force = np.zeros(q.shape[:-1] + (6,))
        force[..., 2] = 1.0
        moment = np.zeros(q.shape[:-1] + (6,))
        moment[..., 3] = q[..., 0] / norm
        moment[..., 4] = -x / norm
        return force, moment


_LAG_BLOCK = 32  # ticks per block of the blocked recurrence in first_order_lag


def _ramp_step(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``e = exp(-r)`` and ``g = (1 - e) / r`` (``1 - r / 2`` for a vanishing ``r``), for a step ``r``.

    One exponential: ``e = 1 + expm1(-r)``, within an ulp of 1 of ``exp(-r)``. ``g`` is written
    over ``r``.
    """
    big = r > 1e-9
    e = np.negative(r)
    np.expm1(e, out=e)
    g = np.divide(e, r, out=r, where=big)
    np.negative(g, out=g, where=big)
    small = ~big
    g[small] = 1.0 - g[small] / 2                                   # g still holds r there
    e += 1.0
    return e, g


def _blocked_recurrence(p: np.ndarray, y: np.ndarray, axis: int) -> None:
    """Solve ``x[t] = a[t] x[t-1] + b[t]`` from ``x[-1] = 0`` in place, in a blocked layout.

    ``y`` holds ``b`` and ``p`` holds ``a`` (broadcastable to ``y``) with the tick within a block
    first and the block on ``axis`` of the rest (``t = block * len(y) + j``); on return ``y``
    holds ``x`` and ``p`` the products of ``a`` within each block. All blocks are run from zero in
    one pass, then the blocks' end states are chained (recursively) and added back scaled by the
    products. With ``0 <= a <= 1`` every step multiplies by factors in [0, 1] and adds, as the
    tick-by-tick loop does: nothing can overflow, at any ``a``.
    """
    tmp = np.empty(y.shape[1:])
    for j in range(1, len(y)):
        np.multiply(p[j], y[j - 1], out=tmp)
        y[j] += tmp
        p[j] *= p[j - 1]
    # x at the end of each block; block i starts from x at the end of block i - 1
    ends = _recurrence(np.moveaxis(p[-1], axis, 0), np.moveaxis(y[-1], axis, 0))
    ends = np.ascontiguousarray(np.moveaxis(ends[:-1], 0, axis))
    later = (slice(None),) * axis + (slice(1, None),)
    tmp = tmp[later]
    for j in range(len(y)):
        np.multiply(p[j][later], ends, out=tmp)
        y[j][later] += tmp


def _recurrence(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``x[t] = a[t] x[t-1] + b[t]`` along axis 0 from ``x[-1] = 0`` (``a`` broadcastable to ``b``)."""
    n, bs = len(b), _LAG_BLOCK
    x = np.array(b, float)
    if n < 2 * bs:
        for k in range(1, n):
            x[k] += a[k] * x[k - 1]
        return x
    nb = n // bs
    m = nb * bs
    perm = (1, 0, *range(2, b.ndim + 1))
    y = np.ascontiguousarray(x[:m].reshape(nb, bs, *b.shape[1:]).transpose(perm))
    p = np.ascontiguousarray(a[:m].reshape(nb, bs, *a.shape[1:]).transpose(perm))
    _blocked_recurrence(p, y, 0)
    x[:m].reshape(nb, bs, *b.shape[1:])[...] = y.transpose(perm)
    for k in range(m, n):
        x[k] += a[k] * x[k - 1]
    return x


def first_order_lag(u: np.ndarray, rate_per_s: np.ndarray | float, dt_s: float) -> np.ndarray:
    """Integrate ``dx/dt = rate (u - x)`` along axis 1 of ``u`` (B, T, ...), from ``x = u[:, 0]``.

    ``rate`` is (B, T) or (B, T, K, ...) for the leading axes of ``u`` (one rate per lag).

    Each step is exact for an input linear over the step at the step's mean rate (first-order
    hold): accurate at the 65 Hz ticks and stable for any ``rate * dt``; the rate may change
    every tick.
    """
    u = np.asarray(u, float)
    rate = np.asarray(rate_per_s, float)
    # the rate may carry trailing axes of u (several lags of one input in one pass)
    rate = np.broadcast_to(rate, u.shape[:max(2, rate.ndim)])
    out = np.empty_like(u)
    out[:, 0] = u[:, 0]
    n, bs, nr = u.shape[1] - 1, _LAG_BLOCK, rate.ndim
    if n < 2 * bs:  # a short series: tick by tick
        r = 0.5 * (rate[:, 1:] + rate[:, :-1]) * dt_s              # (B, T-1, ...) rate * dt per step
        e, g = _ramp_step(r)
        shape = r.shape + (1,) * (u.ndim - nr)
        e, g = e.reshape(shape), g.reshape(shape)
        for k in range(1, n + 1):
            u0, u1 = u[:, k - 1], u[:, k]
            # exact response to a ramp from u0 to u1: x1 = u1 + e (x0 - u0) - (1 - e) / (r dt) (u1 - u0)
            out[:, k] = u1 + e[:, k - 1] * (out[:, k - 1] - u0) - g[:, k - 1] * (u1 - u0)
        return out
    # the same steps for the lag d = x - u: d1 = e d0 + g (u0 - u1) from d = 0, a linear recurrence
    # with known coefficients, solved in blocks of ticks rather than tick by tick. Blocked layout:
    # (tick in block, u's axes beyond rate's, block, B, rate's trailing axes), so that the
    # coefficients broadcast over outer axes only and every operation runs over long rows. The
    # last block is padded with steps that hold d (r = 0, u0 = u1).
    nfull, rem = divmod(n, bs)
    full, nb = nfull * bs, nfull + (rem > 0)
    perm = (2, *range(nr + 1, u.ndim + 1), 1, 0, *range(3, nr + 1))
    back = tuple(np.argsort(perm))

    def parts(x):  # (B, n, ...) -> whole blocks (B, nfull, bs, ...) and the rest (B, rem, ...)
        return x[:, :full].reshape(x.shape[0], nfull, bs, *x.shape[2:]), x[:, full:]

    def blocked(trailing):  # an array in the blocked layout, and its parts as (B, n, ...)
        x = np.empty([(u.shape[0], nb, bs, *trailing)[i] for i in perm])
        v = x.transpose(back)
        if rem:
            v[:, -1, rem:] = 0.0
        return x, (v[:, :nfull], v[:, -1, :rem])

    rate = rate.reshape(rate.shape + (1,) * (u.ndim - nr))         # rate's axes as u's
    r, rs = blocked(rate.shape[2:])
    for r1, r0, rp in zip(parts(rate[:, 1:]), parts(rate[:, :-1]), rs, strict=True):
        np.add(r1, r0, out=rp)
    r *= 0.5
    r *= dt_s                                                       # rate * dt per step
    e, g = _ramp_step(r)
    y, ys = blocked(u.shape[2:])
    for u0, u1, yp in zip(parts(u[:, :-1]), parts(u[:, 1:]), ys, strict=True):
        np.subtract(u0, u1, out=yp)
    y *= g
    _blocked_recurrence(e, y, u.ndim - nr)
    for u1, yp, op in zip(parts(u[:, 1:]), ys, parts(out[:, 1:]), strict=True):
        np.add(u1, yp, out=op)
    return out
