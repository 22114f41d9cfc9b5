"""``mse_after_corrected``: the held-out error against readings corrected by the claimed sensor-side effects.

The readings are made here: a true wrench W = M + e (the model's prediction M plus its own
misfit e), read through a mount mode (bilinear filter written in the test, as a load-cell
program would) and a crosstalk. The corrected error must be e's, whatever the mode amplifies.
"""

import numpy as np
from scipy import signal

from workbench.diagnose.chain import Active, Configuration
from workbench.diagnose.effects.crosstalk import LoadcellCrosstalk
from workbench.diagnose.effects.fluid import AddedMassError
from workbench.diagnose.effects.resonance import StructuralResonance
from workbench.diagnose.evidence_base import RunResidual
from workbench.diagnose.loop_results import corrected_heldout_mse

DT, F_N, ZETA = 1 / 65, 4.5, 0.08


def _mode(w):
    """wn^2 / (s^2 + 2 zeta wn s + wn^2), bilinear at 8x the tick rate, from rest at the first sample."""
    up = signal.resample_poly(w, 8, 1, axis=0, padtype="line")
    wn = 2 * np.pi * F_N
    b, a = signal.bilinear([wn * wn], [1.0, 2 * ZETA * wn, wn * wn], fs=8 / DT)
    zi = signal.lfilter_zi(b, a)[:, None] * up[:1]
    return signal.lfilter(b, a, up, axis=0, zi=zi)[0][::8]


def _run(i, heldout, x, rng):
    t = np.arange(0, 12, DT)
    m = np.stack([np.sin(2 * np.pi * (0.4 + 0.1 * k) * t + i) for k in range(6)], -1)     # the model's wrench
    # the model's own misfit: smooth, broadband up to the 6 Hz cutoff
    e = signal.sosfiltfilt(signal.butter(4, 6.0, fs=1 / DT, output="sos"), rng.normal(0, 0.05, (len(t), 6)), axis=0)
    mix = np.eye(6) + x
    reading = _mode(m + e) @ mix.T
    predicted = _mode(m) @ mix.T
    n = len(t)
    fit = np.zeros(n, bool)
    fit[n // 8: -n // 8] = True
    z = np.zeros(n)
    return RunResidual(f"r{i}", i, heldout, 0.1, 0.5, DT, t, fit, z.astype(bool), z, z, z, z, reading, predicted), e


def test_the_corrected_error_is_the_models_own_misfit_not_its_amplified_reading():
    rng = np.random.default_rng(3)
    x = np.zeros((6, 6))
    x[2, 1] = 0.03                                     # fz reads 3 % of fy
    runs, misfit = [], []
    for i in range(6):
        r, e = _run(i, i % 2 == 0, x, rng)
        runs.append(r)
        if r.heldout:
            misfit.append(e[r.fit])
    own = (np.concatenate(misfit) ** 2).mean(axis=0)
    output = (np.concatenate([r.resid[r.fit] for r in runs if r.heldout]) ** 2).mean(axis=0)
    xt = LoadcellCrosstalk()
    cfg = Configuration([Active(AddedMassError(), {}), Active(StructuralResonance(), {"f_n_hz": F_N, "zeta": ZETA}),
                         Active(xt, {})])
    got = corrected_heldout_mse(runs, cfg, {"loadcell_crosstalk.x_fz_fy": 0.03, "added_mass_error.delta_kg": 0.1})
    got = np.array(list(got.values()))
    assert np.all(output > 1.3 * own)                  # the mode amplifies the misfit near 4.5 Hz
    np.testing.assert_allclose(got, own, rtol=0.03)
    # no sensor-side effect claimed: nothing to correct; a sensor effect that cannot be inverted: not reported
    assert corrected_heldout_mse(runs, Configuration([Active(AddedMassError(), {})]), {}) is None

    class Opaque(StructuralResonance):
        def reading_inverse(self, nl, coefs, dt_s):
            return None

    assert corrected_heldout_mse(runs, Configuration([Active(Opaque(), {"f_n_hz": F_N, "zeta": ZETA})]), {}) is None
