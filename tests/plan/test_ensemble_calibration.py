"""The ensemble's interval: noise and scale fitted on validation readings, coverage measured on others."""

from __future__ import annotations

import numpy as np

from workbench.learn.ensemble import Z90, calibrate, coverage


def _draw(rng, n, k, member_sd, noise_sd, tail=False):
    truth = np.sin(np.linspace(0, 20, n))[:, None] * np.ones(6)
    members = truth[None] + rng.normal(0, member_sd, (k, 1, 6)) + rng.normal(0, member_sd / 3, (k, n, 6))
    # the readings: truth plus noise; 'tail': Student-t noise (heavier tails than the Gaussian interval assumes)
    noise = rng.standard_t(3, (n, 6)) * noise_sd / np.sqrt(3) if tail else rng.normal(0, noise_sd, (n, 6))
    return members, truth + noise


def test_noise_is_recovered_and_the_interval_covers_ninety_percent():
    rng = np.random.default_rng(0)
    val_p, val_y = _draw(rng, 20000, 5, 0.01, 0.2)
    noise, scale = calibrate(val_p, val_y)
    # residual noise 0.2^2 = 0.04 dominates the members' spread: recovered within 5 %
    assert np.allclose(noise, 0.04, rtol=0.05)
    assert np.allclose(scale, 1.0, atol=0.05)
    test_p, test_y = _draw(rng, 20000, 5, 0.01, 0.2)
    cov = coverage(test_p, test_y, noise, scale)
    assert np.all((cov > 0.88) & (cov < 0.92))


def test_members_spread_alone_undercovers_and_scale_fixes_heavy_tails():
    rng = np.random.default_rng(1)
    val_p, val_y = _draw(rng, 20000, 4, 0.02, 0.2, tail=True)
    test_p, test_y = _draw(rng, 20000, 4, 0.02, 0.2, tail=True)
    # the members' spread alone (no noise term) is far too narrow for a reading
    spread_only = coverage(test_p, test_y, np.zeros(6), np.ones(6))
    assert np.all(spread_only < 0.3)
    noise, scale = calibrate(val_p, val_y)
    before = coverage(test_p, test_y, noise, np.ones(6))
    after = coverage(test_p, test_y, noise, scale)
    # t(3) noise scaled to the same variance: the Gaussian 90 % interval over-covers; the fitted scale fixes it
    assert np.all(before > 0.92)
    assert np.all(np.abs(after - 0.9) < 0.015)
    assert np.all(scale < 1) and Z90 > 1.6



def test_run_by_run_scale_covers_ninety_percent_of_each_run_in_ninety_percent_of_runs():
    """Each run carries its own misfit (heavy-tailed across runs) plus tick noise: the run-by-run scale
    makes the interval cover 90 % of a run's readings in 90 % of the validation runs, the pooled one
    only 90 % of all readings."""
    rng = np.random.default_rng(2)
    n_runs, ticks = 40, 300
    truth = np.sin(np.linspace(0, 30, n_runs * ticks))[:, None] * np.ones(6)
    members = truth[None] + rng.normal(0, 0.05, (4, n_runs * ticks, 6))
    y = truth + np.repeat(rng.standard_t(2, (n_runs, 6)) * 0.3, ticks, axis=0) + rng.normal(0, 0.1, truth.shape)
    runs = np.repeat(np.arange(n_runs), ticks)
    noise, pooled = calibrate(members, y)
    _, by_run = calibrate(members, y, runs)
    per_run = np.array([coverage(members[:, runs == r], y[runs == r], noise, by_run) for r in range(n_runs)])
    per_run_pooled = np.array([coverage(members[:, runs == r], y[runs == r], noise, pooled)
                               for r in range(n_runs)])
    assert np.all(np.abs((per_run >= 0.9).mean(0) - 0.9) <= 0.05)
    assert np.all(np.abs(coverage(members, y, noise, pooled) - 0.9) < 0.005)
    assert (per_run_pooled >= 0.9).mean() < (per_run >= 0.9).mean()
