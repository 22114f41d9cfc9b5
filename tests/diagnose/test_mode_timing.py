"""The mount mode's damping error carries the base model's timing (issue 13; docs/diagnose.md section 7).

A delay d of the readings behind the prediction reads as 2 zeta / wn more, so a base model whose misfit
follows the rate of its own force moves zeta by wn d / 2 (1 ms: 0.014 at 4.5 Hz). The runs here are
made by the test: a prediction of stroke harmonics, the reading that prediction shifted in time by a
per-run delay (interpolated, not a derivative) plus noise.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest


def _wave(tt, f, amps):
    """Three stroke harmonics at gait frequency ``f``, amplitudes ``amps`` (3, 6) per channel."""
    return sum(np.outer(np.sin(2 * np.pi * (k + 1) * f * tt + k), amps[k]) for k in range(3))


def _runs(delays_s, seed=0, dt=1 / 65):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 12.0, dt)
    runs = []
    for d in delays_s:
        f = rng.uniform(0.6, 1.6)
        amps = rng.uniform(0.2, 1.0, (3, 6))
        pred = _wave(t, f, amps)
        meas = _wave(t - d, f, amps) + 0.002 * rng.standard_normal(pred.shape)
        runs.append(SimpleNamespace(fit=(t > 0.5) & (t < t[-1] - 0.5), dt_s=dt, predicted=pred, measured=meas,
                                    resid=meas - pred))
    return runs


def test_each_runs_delay_is_read_from_its_residual():
    from workbench.diagnose.effects.resonance import timing_scatter

    planted = np.random.default_rng(1).normal(0.0, 0.004, 30)
    got = timing_scatter(_runs(planted))
    assert got == pytest.approx(planted, abs=2e-4)


def test_the_damping_error_grows_by_the_timing_scatter_and_nothing_else_moves():
    from workbench.diagnose.effects.resonance import StructuralResonance

    planted = np.random.default_rng(2).normal(0.0, 0.010, 40)
    params = {"f_n_hz": 4.5, "zeta": 0.08}
    stderr = {"f_n_hz": 0.01, "zeta": 0.005}
    StructuralResonance().complete(params, stderr, SimpleNamespace(weights=np.ones(6)), None, _runs(planted))
    timing = 2 * np.pi * 4.5 / 2 * np.std(planted, ddof=1) / np.sqrt(len(planted))   # wn / 2 x the delay's error
    assert stderr["zeta"] == pytest.approx(np.hypot(0.005, timing), rel=0.05)
    assert stderr["zeta"] > 0.015 and stderr["f_n_hz"] == 0.01 and params == {"f_n_hz": 4.5, "zeta": 0.08}
    # runs that agree in time leave the error as it was (to the noise's share)
    calm = {"zeta": 0.005}
    StructuralResonance().complete(params, calm, SimpleNamespace(weights=np.ones(6)), None, _runs(np.zeros(40)))
    assert calm["zeta"] == pytest.approx(0.005, rel=0.05)
