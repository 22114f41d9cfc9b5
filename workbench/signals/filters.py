"""Zero-phase low-pass filtering, uniform resampling and smoothed derivatives (scipy.signal).

The low-pass runs forward and backward (``sosfiltfilt``), so it adds no phase lag: a force
peak stays at the tick where it happened and real delays in the physics (servo lag, added-mass
phase) stay visible. The forward-backward pass squares the magnitude response; the one-pass
Butterworth cutoff is raised so that the *combined* response is -3 dB at the requested cutoff.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np


def single_pass_cutoff(cutoff_hz: float, order: int) -> float:
    """One-pass Butterworth cutoff whose forward-backward response is -3 dB at ``cutoff_hz``.

    A Butterworth pass has |H|^2 = 1 / (1 + (f/fc)^(2N)); the zero-phase filter applies it twice,
    so |H|^2 = 1/2 at f needs (f/fc)^(2N) = sqrt(2) - 1.
    """
    return cutoff_hz / (np.sqrt(2.0) - 1.0) ** (1.0 / (2 * order))


@lru_cache(maxsize=64)
def _design(cutoff_hz: float, order: int, fs_hz: float) -> np.ndarray:
    from scipy import signal  # imported on first use: a second off the start of every command

    return signal.butter(order, single_pass_cutoff(cutoff_hz, order), btype="low", fs=fs_hz, output="sos")


def can_lowpass(cutoff_hz: float, order: int, fs_hz: float) -> bool:
    """Whether the sampling rate leaves room for the filter (its cutoff below 90 % of Nyquist)."""
    return single_pass_cutoff(cutoff_hz, order) < 0.45 * fs_hz


def lowpass(x: np.ndarray, fs_hz: float, cutoff_hz: float = 6.0, order: int = 4, axis: int = 0) -> np.ndarray:
    """Zero-phase Butterworth low-pass of uniformly sampled ``x`` along ``axis``.

    Returns ``x`` unchanged when the sampling rate is too low for the cutoff (the signal holds
    nothing above it to remove) or when the record is shorter than the filter's edge padding.
    """
    x = np.asarray(x, dtype=float)
    if not can_lowpass(cutoff_hz, order, fs_hz):
        return x.copy()
    # the design depends on the rate only through cutoff/fs: a few ppm of clock drift is no new design
    sos = _design(float(cutoff_hz), int(order), round(float(fs_hz), 3))
    padlen = 3 * (2 * len(sos) + 1)
    if x.shape[axis] <= padlen:
        return x.copy()
    from scipy import signal

    return signal.sosfiltfilt(sos, x, axis=axis)


def lowpass_sampled(t: np.ndarray, x: np.ndarray, cutoff_hz: float = 6.0, order: int = 4) -> np.ndarray:
    """:func:`lowpass` for samples at times ``t`` that may jitter: filtered on a uniform grid, mapped back."""
    t = np.asarray(t, float)
    if is_uniform(t):
        return lowpass(x, (len(t) - 1) / (t[-1] - t[0]), cutoff_hz, order)
    grid, dt = uniform_grid(t)
    return resample_linear(grid, lowpass(resample_linear(t, x, grid), 1.0 / dt, cutoff_hz, order), t)


def frequency_response_db(freqs_hz: np.ndarray, fs_hz: float, cutoff_hz: float = 6.0, order: int = 4) -> np.ndarray:
    """Gain (dB) of the zero-phase filter :func:`lowpass` applies, at ``freqs_hz``."""
    from scipy import signal

    sos = _design(float(cutoff_hz), int(order), float(fs_hz))
    _, h = signal.sosfreqz(sos, worN=np.asarray(freqs_hz, float), fs=fs_hz)
    return 20 * np.log10(np.maximum(np.abs(h) ** 2, 1e-300))


def uniform_grid(t: np.ndarray) -> tuple[np.ndarray, float]:
    """A uniform time grid over ``t`` at its median step; returns (grid, step)."""
    t = np.asarray(t, float)
    dt = float(np.median(np.diff(t)))
    n = int(np.floor((t[-1] - t[0]) / dt + 1e-9)) + 1
    return t[0] + dt * np.arange(n), dt


def resample_linear(t: np.ndarray, x: np.ndarray, t_new: np.ndarray) -> np.ndarray:
    """Linear interpolation of each column of ``x`` (N,) or (N, C) from times ``t`` onto ``t_new``."""
    x = np.asarray(x, float)
    if x.ndim == 1:
        return np.interp(t_new, t, x)
    return np.stack([np.interp(t_new, t, x[:, c]) for c in range(x.shape[1])], axis=1)


def is_uniform(t: np.ndarray, tolerance: float = 0.01) -> bool:
    """True when every step of ``t`` is within ``tolerance`` (fraction) of the median step."""
    d = np.diff(np.asarray(t, float))
    if len(d) == 0:
        return True
    med = np.median(d)
    return bool(np.all(np.abs(d - med) <= tolerance * med))


def derivative(t: np.ndarray, x: np.ndarray, window: int = 7, polyorder: int = 3) -> np.ndarray:
    """Time derivative by a Savitzky-Golay fit (local polynomial of ``polyorder`` over ``window`` samples).

    On jittery time stamps the signal is first put on a uniform grid, differentiated there and
    mapped back, so the local polynomial sees the true spacing.
    """
    t = np.asarray(t, float)
    x = np.asarray(x, float)
    n = len(t)
    if n < 2:
        return np.zeros_like(x)
    window = min(window, n if n % 2 else n - 1)
    if window <= polyorder:
        return np.gradient(x, t, axis=0)
    if is_uniform(t):
        dt = (t[-1] - t[0]) / (n - 1)
        return _savgol_derivative(x, window, polyorder, dt)
    grid, dt = uniform_grid(t)
    dg = _savgol_derivative(resample_linear(t, x, grid), window, polyorder, dt)
    return resample_linear(grid, dg, t)


@lru_cache(maxsize=16)
def _savgol_operators(window: int, polyorder: int) -> tuple[np.ndarray, np.ndarray]:
    """Interior kernel and edge matrix (first half-window samples) of the SG first derivative, dt = 1."""
    from scipy import signal

    kernel = signal.savgol_coeffs(window, polyorder, deriv=1, use="conv")
    half = window // 2
    # edges: fit the polynomial to the first `window` samples, differentiate it at samples 0..half-1
    pos = np.arange(window, dtype=float)
    vander = np.vander(pos, polyorder + 1, increasing=True)          # (window, p+1)
    fit = np.linalg.pinv(vander)                                       # coefficients = fit @ x
    powers = np.arange(1, polyorder + 1)
    dvander = np.zeros((half, polyorder + 1))
    dvander[:, 1:] = powers * pos[:half, None] ** (powers - 1)
    return kernel, dvander @ fit                                       # (half, window)


def _savgol_derivative(x: np.ndarray, window: int, polyorder: int, dt: float) -> np.ndarray:
    """Savitzky-Golay first derivative along axis 0 (scipy's ``mode="interp"``), with cached operators."""
    kernel, edge = _savgol_operators(window, polyorder)
    half = window // 2
    x = np.asarray(x, float)
    flat = x.reshape(len(x), -1)
    out = np.empty_like(flat)
    for j in range(flat.shape[1]):
        out[half:-half, j] = np.convolve(flat[:, j], kernel, mode="valid")
    out[:half] = edge @ flat[:window]
    out[-half:] = -(edge @ flat[::-1][:window])[::-1]
    return (out / dt).reshape(x.shape)
