"""A structural mode of the mount between leg and load cell (``structural_resonance``; docs/diagnose.md)."""

from __future__ import annotations

import numpy as np
from scipy import signal

from workbench.diagnose.effects.base import Effect, SearchParam
from workbench.diagnose.evidence import ccf_clause


def _mode_coefficients(f_n_hz: float, zeta: float, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear discretisation of wn^2 / (s^2 + 2 zeta wn s + wn^2), prewarped at wn (exact there)."""
    wn = 2 * np.pi * f_n_hz
    k = wn / np.tan(wn * dt_s / 2)
    a0 = k * k + 2 * zeta * wn * k + wn * wn
    b = np.array([wn * wn, 2 * wn * wn, wn * wn]) / a0
    a = np.array([1.0, (2 * wn * wn - 2 * k * k) / a0, (k * k - 2 * zeta * wn * k + wn * wn) / a0])
    return b, a


_UPSAMPLED: dict = {}


def _upsampled(w: np.ndarray, factor: int, axis: int) -> np.ndarray:
    """Band-limited interpolation by ``factor`` along ``axis``, remembered for the last array seen.

    A search over the mode's frequency filters the same cached stack many times.
    """
    key = (id(w), w.shape, factor, axis)
    hit = _UPSAMPLED.get("last")
    if hit is not None and hit[0] == key and hit[1] is w:
        return hit[2]
    up = signal.resample_poly(w, factor, 1, axis=axis, padtype="line")
    _UPSAMPLED["last"] = (key, w, up)
    return up


def resonance_filter(w: np.ndarray, dt_s: float, f_n_hz: float, zeta: float, axis: int = -2,
                     oversample: int = 2) -> np.ndarray:
    """Pass w through wn^2 / (s^2 + 2 zeta wn s + wn^2) along ``axis``, starting at rest on the first sample.

    The signal is interpolated ``oversample`` times (band-limited) and filtered there with a
    bilinear discretisation prewarped at the mode: at the 65 Hz ticks alone a 4 Hz mode would be
    off by about a percent, which the best-resolved channels notice.
    """
    w = np.asarray(w, float)
    ax = axis % w.ndim
    w_up = _upsampled(w, oversample, ax) if oversample > 1 else w
    b, a = _mode_coefficients(f_n_hz, zeta, dt_s / oversample)
    x0 = np.take(w_up, [0], axis=ax)
    zi = signal.lfilter_zi(b, a).reshape([-1 if i == ax else 1 for i in range(w.ndim)]) * x0
    y, _ = signal.lfilter(b, a, w_up, axis=ax, zi=zi)
    if oversample > 1:
        y = np.take(y, np.arange(0, w.shape[ax] * oversample, oversample), axis=ax)
    return y


class StructuralResonance(Effect):
    """Reading = true wrench through a 2nd-order mode wn^2 / (s^2 + 2 zeta wn s + wn^2), all channels."""

    name = "structural_resonance"
    ranges = {"f_n_hz": (0.7, 12.0), "zeta": (0.0, 1.0)}
    stage = "filter"
    physical = False
    formula = "W_read = W wn^2 / (s^2 + 2 zeta wn s + wn^2), wn = 2 pi f_n_hz"
    # a scan in frequency at moderate damping (a sharp mode is missed between coarse points), then a
    # 2-D refinement of frequency and damping from the best point
    search = (SearchParam("f_n_hz", tuple(np.round(np.arange(1.0, 8.01, 0.25), 2)), (0.5, 12.0)),
              SearchParam("zeta", (0.12,), (0.005, 1.5), log=True))
    location_params = ("f_n_hz", "zeta")

    def refusal(self, params: dict, settings) -> str | None:
        """A heavily damped mode is a delay in disguise (mount and sting modes are lightly damped)."""
        zeta, limit = params.get("zeta"), getattr(settings, "max_mode_zeta", 0.3)
        if isinstance(zeta, (int, float)) and zeta > limit:
            return (f"zeta = {zeta:.2f} > {limit:g}: a heavily damped mode is a delay (servo or circulatory lag), "
                    "not a mount mode")
        return None

    def hint(self, ev, params: dict) -> str:  # noqa: D102
        return ccf_clause(ev, "model_force_accel", "the second derivative of the model's force")

    def filter_wrench(self, w: np.ndarray, dt_s: float, nl: dict) -> np.ndarray:  # noqa: D102
        return resonance_filter(w, dt_s, nl["f_n_hz"], nl["zeta"], axis=-2)


LIBRARY_RANK = 4  # place in the library's order (workbench.diagnose.library._in_tree)

EFFECTS = (StructuralResonance,)
