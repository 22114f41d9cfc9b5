"""The dependence evidence's correlations, computed with one FFT per run and input, against the
textbook sums written here (np.correlate channel by channel, Bartlett's variance)."""

from __future__ import annotations

import numpy as np

from workbench.diagnose.evidence_base import EvidenceSettings, RunResidual
from workbench.diagnose.evidence_dependence import correlations


def _run(rng, n: int, i: int) -> RunResidual:
    t = np.arange(n) * 0.01
    measured = np.cumsum(rng.normal(size=(n, 6)), axis=0) * 0.01 + rng.normal(size=(n, 6))
    measured[:, 5] = 0.25  # a channel the model fits exactly: its residual is constant
    fit = np.ones(n, bool)
    fit[: n // 10] = False  # the settling stretch left out
    return RunResidual(f"r{i}", i, False, 0.2, 0.5, 0.01, t, fit, ~fit, np.sin(t), np.cos(t), np.cos(t), -np.sin(t),
                       measured, np.zeros((n, 6)))


def _corr(a: np.ndarray, b: np.ndarray, lag: int) -> float:
    """corr(a_t, b_{t+lag}) with both scaled to unit variance, divided by n (the biased estimate)."""
    a = (a - a.mean()) / a.std()
    b = (b - b.mean()) / b.std()
    n = len(a)
    return float(np.dot(a[max(0, -lag): n - max(0, lag)], b[max(0, lag): n - max(0, -lag)]) / n)


def test_fft_correlations_equal_the_sums_channel_by_channel():
    rng = np.random.default_rng(3)
    runs = [_run(rng, n, i) for i, n in enumerate((700, 540, 900))]
    inputs = {
        "angle": [r.theta_h + 0.3 * rng.normal(size=len(r.theta_h)) for r in runs],  # one series for all channels
        "force": [np.column_stack([rng.normal(size=len(r.theta_h)) for _ in range(5)] + [np.ones(len(r.theta_h))])
                  for r in runs],  # six series, one constant
    }
    s = EvidenceSettings()
    lags, acf, bound_white, ccf = correlations(runs, inputs, s)
    lmax = len(lags) - 1
    for name, series in inputs.items():
        r_want = np.zeros((2 * lmax + 1, 6))
        v_want = np.zeros((2 * lmax + 1, 6))
        n_sum = 0
        for run, x in zip(runs, series, strict=True):
            e = run.resid[run.fit]
            xx = np.asarray(x)[run.fit]
            xx = np.repeat(xx[:, None], 6, axis=1) if xx.ndim == 1 else xx
            n = len(e)
            used = False
            for c in range(6):
                if xx[:, c].std() < 1e-12 or e[:, c].std() == 0:
                    continue
                rho_x = np.array([_corr(xx[:, c], xx[:, c], j) for j in range(1, lmax + 1)])
                rho_e = np.array([_corr(e[:, c], e[:, c], j) for j in range(1, lmax + 1)])
                bart = (1 + 2 * (rho_x * rho_e).sum()) / n
                r_want[:, c] += [n * _corr(xx[:, c], e[:, c], k) for k in range(-lmax, lmax + 1)]
                v_want[:, c] += max(bart, 1.0 / n) * n * n
                used = True
            n_sum += n if used else 0
        got = ccf[name]
        live = v_want[0] > 0
        np.testing.assert_allclose(got["r"][:, live], r_want[:, live] / n_sum, atol=1e-12)
        np.testing.assert_allclose(got["bound"][:, live], 2.58 * np.sqrt(v_want[:, live]) / n_sum, rtol=1e-9)
        assert np.all(got["r"][:, 5] == 0)  # the constant residual channel correlates with nothing
    e0 = runs[0].resid[runs[0].fit][:, 0]
    assert abs(acf[3, 0] - np.average([_corr(r.resid[r.fit][:, 0], r.resid[r.fit][:, 0], 3) for r in runs],
                                      weights=[r.fit.sum() for r in runs])) < 1e-12
    assert acf[0, 0] == 1.0 and len(e0) == 630
    assert abs(bound_white - 2.58 / np.sqrt(sum(r.fit.sum() for r in runs))) < 1e-15
