"""Crosstalk beside a base model's own misfit (issue 13: a learned base's fz error followed its fy).

A misfit of the force model is a wrench acting on the leg, so it shows in every channel at once
(a force at a point off the load cell's axis gives moments as well); a load-cell crosstalk adds a
share of one channel's reading to one other channel only. The crosstalk's columns are estimated
beside the other channels' residuals (``misfit_free``) on training runs. Planted here with the
test's own formulas: a leg-plane force at a moving point, a base model that misses part of it
(a gain and a lag of its own), and a 3 % fz-from-fy crosstalk.
"""

from pathlib import Path

import numpy as np
import pytest

from workbench.diagnose.effects.crosstalk import misfit_free

DT = 0.01


def _wrench(f_y, f_z, px, py, x_off):
    """(fx, fy, fz, tx, ty, tz) of a leg-plane force (f_y, f_z) at (x_off, px, py): r x F."""
    return np.stack([np.zeros_like(f_y), f_y, f_z, px * f_z - py * f_y, -x_off * f_z, x_off * f_y], axis=-1)


def _late(x, lag_s=0.04):
    """``x`` later by ``lag_s`` (whole ticks, the first value held)."""
    n = int(round(lag_s / DT))
    return np.concatenate([np.full(n, x[0]), x[:-n]])


def _runs(n_runs=12, seconds=12.0, share=0.03, seed=3):
    """Readings and a model's prediction (B, T, 6): the model misses 15 % of the force and lags it by 40 ms."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, seconds, DT)
    reads, preds = [], []
    for _ in range(n_runs):
        f = rng.uniform(0.3, 0.6)
        ph = rng.uniform(0, 2 * np.pi, 4)
        w = 2 * np.pi * f
        fy = 0.3 * np.sin(w * t + ph[0]) + 0.1 * np.sin(2 * w * t + ph[1])
        fz = 0.25 * np.cos(w * t + ph[0]) + 0.08 * np.sin(3 * w * t + ph[2])
        px = 0.15 + 0.05 * np.sin(w * t + ph[3])
        py = -0.12 + 0.04 * np.cos(w * t + ph[3])
        true = _wrench(fy, fz, px, py, 0.02)
        model = _wrench(0.85 * _late(fy), 0.85 * _late(fz), px, py, 0.02)
        read = true + 1e-3 * rng.normal(size=true.shape) * np.array([1, 1, 1, 0.1, 0.01, 0.01])
        read[:, 2] += share * read[:, 1]
        reads.append(read)
        preds.append(model)
    return np.array(reads), np.array(preds)


def _entry(reads, preds, guard):
    resid = reads - preds
    src = preds[..., 1]
    if guard:
        src = misfit_free(src, np.delete(resid, 2, axis=-1), np.ones(src.shape, bool))
    return float((src * resid[..., 2]).sum() / (src * src).sum())


@pytest.mark.parametrize("share", [0.03, 0.0])
def test_a_crosstalk_is_told_from_a_misfit_that_shows_in_every_channel(share):
    reads, preds = _runs(share=share)
    plain = _entry(reads, preds, guard=False)
    guarded = _entry(reads, preds, guard=True)
    # the model's own fz misfit follows fy: the plain entry is far off (it reads a crosstalk that is not there)
    assert abs(plain - share) > 0.01, plain
    assert guarded == pytest.approx(share, abs=0.003), (plain, guarded)


@pytest.mark.slow
def test_fed_lstm_base_names_a_10pc_crosstalk_at_its_value():
    """With the trained FED-LSTM as base and no reference, a 10 % fz-from-fy crosstalk (missed before) is named.

    Before the misfit guard a 6 % one came out at 0.103 beside a false ``x_ty_tz`` and a 10 % one
    was not named; the entry must now be the planted one, within 20 %, alone.
    """
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    import battery
    import planting

    model = Path(__file__).resolve().parents[2] / "datasets" / "models" / "fed-lstm"
    if not (model / "model.json").is_file():
        pytest.skip("the trained FED-LSTM (datasets/models/fed-lstm) is made by dvc repro")
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        bench = battery.Bench(Path(tmp), n_sets=12)

        def plant(lc, mo, run):                      # the test's own formula: fz reads 10 % of fy
            lc["fz_n"] = lc["fz_n"] + 0.10 * lc["fy_n"]

        dst = planting.copy_campaign(bench.new_campaign(), Path(tmp) / "xt10", [plant])
        d = bench.diagnose(bench.frame(dst), str(model), False)
    named = {e.name: e for e in d.effects}
    assert "loadcell_crosstalk" in named, [e.name for e in d.effects]
    params = named["loadcell_crosstalk"].params
    assert params["x_fz_fy"] == pytest.approx(0.10, rel=0.2), params
    assert set(params) == {"x_fz_fy"}, params
