"""The ensemble's interval: noise and scale fitted on validation readings, coverage measured on others."""

from __future__ import annotations

import numpy as np

from workbench.learn.ensemble import Z90, _scores, calibrate, coverage


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


def _runs(rng, n_runs, ticks, misfit_df=2):
    """Runs of a model whose error is mostly a whole-run misfit (Student-t across runs) plus tick noise."""
    truth = np.sin(np.linspace(0, 30, n_runs * ticks))[:, None] * np.ones(6)
    members = truth[None] + rng.normal(0, 0.05, (4, n_runs * ticks, 6))
    y = truth + np.repeat(rng.standard_t(misfit_df, (n_runs, 6)) * 0.3, ticks, axis=0) + rng.normal(0, 0.1,
                                                                                                   truth.shape)
    return members, y, np.repeat(np.arange(n_runs), ticks)


def test_leave_one_run_out_scale_covers_ninety_percent_of_new_runs_where_pooled_undercovers():
    """Readings of one run share its misfit: a pooled 90 % quantile of 15 validation runs covers less
    than 90 % of new runs' readings; holding out whole runs on validation finds the level that
    covers 90 % of new runs (measured on 400 fresh runs per replicate, nothing fitted on them)."""
    rng = np.random.default_rng(2)
    loro, pooled = [], []
    for _ in range(12):
        vp, vy, vr = _runs(rng, 15, 120)
        tp, ty, _ = _runs(rng, 400, 20)
        detail: dict = {}
        noise, scale = calibrate(vp, vy, vr, detail=detail)
        _, z = _scores(vp, vy)
        loro.append(coverage(tp, ty, noise, scale))
        pooled.append(coverage(tp, ty, noise, np.quantile(z, 0.9, axis=0) / Z90))
        # the search's own record: each channel's level reaches 90 % leave-one-run-out coverage on validation
        assert all(v >= 0.9 for v in detail["coverage_val_loro"].values())
        assert all(0.9 <= v <= 1.0 for v in detail["level"].values())
    # the six channels are drawn alike: average them with the replicates
    loro, pooled = float(np.mean(loro)), float(np.mean(pooled))
    assert pooled < 0.89
    assert loro > pooled + 0.005
    assert abs(loro - 0.9) < 0.015, loro


def test_few_runs_fall_back_to_split_conformal_on_readings():
    rng = np.random.default_rng(3)
    vp, vy = _draw(rng, 999, 4, 0.01, 0.2)
    noise, scale = calibrate(vp, vy, np.zeros(999, int))
    _, z = _scores(vp, vy)
    # level ceil(1000 * 0.9) / 999 = 900 / 999: the 900th smallest score of 999
    assert np.allclose(scale * Z90, np.sort(z, axis=0)[899], rtol=1e-9, atol=1e-12)
