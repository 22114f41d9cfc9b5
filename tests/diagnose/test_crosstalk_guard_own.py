"""A crosstalk's misfit guard takes the other channels' residuals after the crosstalk itself (``guard_own``).

Made here with the test's own formulas: a leg-plane force at a moving point; the base model
misses a lateral force g(t) acting at a fixed point (so fy's misfit is g and tx's is 0.12 g: fy's
misfit follows tx's), and the load cell's tx reads 2 % of fz. An entry into fy estimated beside
the tx residual that still holds 0.02 fz reads about -0.02 / 0.12 = -0.17 (the demo campaign's
false ``x_fy_fz`` -0.052 beside a planted tx-from-fz crosstalk, 29 Nov 2026); beside the tx
residual taken after the fitted tx-from-fz entry it reads about 0.
"""

from types import SimpleNamespace

import numpy as np

from workbench.diagnose.effects.crosstalk import LoadcellCrosstalk, misfit_free

DT = 0.01


def _runs(n_runs=10, seconds=12.0, seed=5):
    rng = np.random.default_rng(seed)
    t = np.arange(0, seconds, DT)
    reads, preds = [], []
    for _ in range(n_runs):
        w = 2 * np.pi * rng.uniform(0.3, 0.6)
        ph = rng.uniform(0, 2 * np.pi, 4)
        fy = 0.3 * np.sin(w * t + ph[0]) + 0.1 * np.sin(2 * w * t + ph[1])
        fz = 0.25 * np.cos(w * t + ph[0]) + 0.08 * np.sin(3 * w * t + ph[2])
        px, py = 0.15 + 0.05 * np.sin(w * t + ph[3]), -0.12 + 0.04 * np.cos(w * t + ph[3])
        model = np.stack([0 * fy, fy, fz, px * fz - py * fy, -0.02 * fz, 0.02 * fy], axis=-1)
        g = 0.05 * np.sin(1.7 * w * t + ph[1]) + 0.03 * np.cos(2.9 * w * t)        # the missed lateral force
        true = model + np.stack([0 * g, g, 0 * g, 0.12 * g, 0 * g, 0 * g], axis=-1)  # at (0, 0, -0.12)
        read = true + 1e-3 * rng.normal(size=true.shape) * np.array([1, 1, 1, 0.1, 0.01, 0.01])
        read[:, 3] += 0.02 * read[:, 2]                                            # tx reads 2 % of fz
        reads.append(read)
        preds.append(model)
    return np.array(reads), np.array(preds)


def _fy_from_fz(effect, reads, preds, coefs):
    """The entry x_fy_fz estimated on the guarded column (what ``sensor_terms`` builds on training runs)."""
    ctx = SimpleNamespace(rs=SimpleNamespace(y=reads), coefs=coefs)
    others = np.delete(effect._residual(ctx, preds), 1, axis=-1)
    col = misfit_free(preds[..., 2], others, np.ones(preds.shape[:2], bool))
    resid_fy = reads[..., 1] - preds[..., 1]
    return float((col * resid_fy).sum() / (col * col).sum())


def test_the_guard_after_the_fitted_crosstalk_reads_no_false_entry():
    reads, preds = _runs()
    effect = LoadcellCrosstalk()
    fitted = {"loadcell_crosstalk.x_tx_fz": 0.02}
    before = _fy_from_fz(effect, reads, preds, {})           # the entry before tx-from-fz has a value
    after = _fy_from_fz(effect, reads, preds, fitted)        # at the fixed point
    assert abs(before - (-0.02 / 0.12)) < 0.01, before   # -0.167: fy follows tx, which holds 0.02 fz
    assert abs(after) < 0.01, after
    # without guard_own the fitted entry changes nothing
    plain = LoadcellCrosstalk(guard_own=False)
    assert _fy_from_fz(plain, reads, preds, fitted) == before
