"""The force's flow sensitivity ``U dF/dU`` measured across a campaign's flow speeds.

A tone in the tunnel's flow, ``U(t) = U (1 + a sin(2 pi f t))``, changes the true force by
``a sin(2 pi f t) U dF/dU``: it multiplies the *true* flow sensitivity, not the diagnosed
model's. When the campaign runs the same motion at several flow speeds (the tunnel protocol:
every parameter set at every speed), that sensitivity is in the readings themselves: at each
instant of the stroke (time since the run's first trigger edge) a polynomial in U through the
readings at every speed gives ``dF/dU``. The model's own ``U dM/dU`` is only as good as the
model; without a reference campaign the EF on real water is far from the truth, and a tone fitted
on the EF's sensitivity leaves much of its line (issue 13).

Only the tone's *shape* in each run comes from here; its amplitude and phase are still fitted.
"""

from __future__ import annotations

import numpy as np

#: motion parameters that define a parameter set (the flow speed is what varies across its runs)
_KEYS = ("theta_h_min_deg", "theta_h_max_deg", "theta_k_min_deg", "theta_k_max_deg", "frequency_hz", "phi_rad",
         "alpha_rad")


def _set_key(params: dict) -> tuple | None:
    if not params or "frequency_hz" not in params:
        return None
    return tuple(round(float(params.get(k, 0.0)), 3) + 0.0 for k in _KEYS)


def measured_sensitivity(sets, min_speeds: int = 3) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per run id: ``(time_s, U dF/dU)`` on the run's valid ticks, from the readings of its parameter set.

    ``sets``: the campaign's run batches (:class:`~workbench.diagnose.data.RunSet`). A set needs
    at least ``min_speeds`` distinct flow speeds (zero counts: the force at rest in still water
    anchors the polynomial); the polynomial's degree is the number of speeds minus one, at most
    two (drag is quadratic in U, a quasi-steady added mass does not depend on it). Runs of sets
    with fewer speeds are left out (the caller falls back on the model's sensitivity).
    Readings are used as they are: a per-run bias changes ``dF/dU`` by a constant, which the
    tone's fitted amplitude does not care for.
    """
    groups: dict[tuple, list[tuple[str, float, np.ndarray, np.ndarray]]] = {}
    for rs in sets:
        for i in range(rs.shape[0]):
            key = _set_key(rs.params[i])
            if key is None:
                continue
            v = rs.valid[i]
            groups.setdefault(key, []).append((rs.run_ids[i], float(rs.flow[i]), rs.time_s[i, v], rs.y[i, v]))
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for runs in groups.values():
        # one run per speed (a repeated speed: the first)
        by_u: dict[float, tuple] = {}
        for r in runs:
            by_u.setdefault(round(r[1], 4), r)
        if len(by_u) < min_speeds:
            continue
        speeds = np.array(sorted(by_u))
        deg = min(2, len(speeds) - 1)
        v = np.vander(speeds, deg + 1)          # U^deg ... 1
        pinv = np.linalg.pinv(v)                  # (deg + 1, n_speeds)
        for rid, u, t, _ in runs:
            # every speed's readings at this run's instants of the stroke
            f = np.stack([np.column_stack([np.interp(t, by_u[s][2], by_u[s][3][:, c]) for c in range(6)])
                          for s in speeds])       # (n_speeds, T, 6)
            coef = np.einsum("ks,stc->ktc", pinv, f)
            # d/dU of sum_k coef_k U^(deg - k), times U
            slope = sum((deg - k) * coef[k] * u ** (deg - k - 1) for k in range(deg))
            out[rid] = (np.asarray(t, float), u * slope)
    return out


def without_stroke(cols: np.ndarray, time_s: np.ndarray, mask: np.ndarray, freq: np.ndarray,
                   cutoff_hz: float = 6.0, max_harmonics: int = 12) -> np.ndarray:
    """``cols`` (B, T, 6) with each run's stroke-locked part (mean and gait harmonics below the cutoff) taken out.

    The projection is fitted on the run's ``mask`` ticks and removed from all of them. A tone's
    column ``g sin(2 pi f t)`` then holds only what the stroke cannot: where ``f`` sits on a gait
    harmonic of the run, next to nothing is left, and that run's tone is not told from the
    base model's stroke-locked misfit (which would otherwise set its amplitude and phase).
    """
    out = np.array(cols, float)
    for i in range(out.shape[0]):
        m = np.asarray(mask[i], bool)
        if not np.isfinite(freq[i]) or freq[i] <= 0 or m.sum() < 8:
            continue
        t = time_s[i]
        k = min(max(1, int(np.floor(cutoff_hz / freq[i]))), max_harmonics, max(1, (int(m.sum()) - 2) // 4))
        w = 2 * np.pi * freq[i] * t
        j = np.arange(1, k + 1)
        x = np.concatenate([np.ones((len(t), 1)), np.sin(np.outer(w, j)), np.cos(np.outer(w, j))], axis=1)
        xm = x[m]
        g = xm.T @ xm
        coef = np.linalg.solve(g + 1e-9 * np.trace(g) / len(g) * np.eye(len(g)), xm.T @ out[i][m])
        out[i] -= x @ coef
    return out


def on_harmonic(tone_hz: float, freq: np.ndarray, duration_s: np.ndarray, tolerance: float = 0.8) -> np.ndarray:
    """Per run: whether ``tone_hz`` lies within ``tolerance / duration`` of a harmonic of its gait frequency."""
    f = np.asarray(freq, float)
    ok = np.isfinite(f) & (f > 0)
    k = np.where(ok, np.round(tone_hz / np.where(ok, f, 1.0)), 0.0)
    dist = np.abs(tone_hz - k * np.where(ok, f, 0.0))
    return ok & (k >= 1) & (dist < tolerance / np.maximum(np.asarray(duration_s, float), 1e-9))
