"""The ground truth: EF mode is the EF, the rich truth follows the EF's trend but misses it by far more than noise."""

import json

import numpy as np
import pytest
from scipy import signal

from workbench.errors import ModelError
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.motion import JointSinusoid, LegMotion
from workbench.virtual_lab.physics import TrueLegModel, TruthSettings, first_order_lag
from workbench.virtual_lab.settings import FLOW_SPEEDS_MPS, LoadCellSettings, demo_grid

RATE = 130.0  # twice the control rate: the truth's lag states integrate accurately


def grid_motion(grid, u, cycles=5, rate=RATE):
    """The prescribed motion of every set (padded with rest), and a mask of the moving samples."""
    rows = []
    for p in grid:
        js = JointSinusoid.from_params(p)
        t = np.arange(int(round(cycles / p["frequency_hz"] * rate))) / rate
        rows.append(js.evaluate(t))
    n = max(len(r[0]) for r in rows)
    arr = np.zeros((6, len(rows), n))
    mask = np.zeros((len(rows), n), bool)
    for i, r in enumerate(rows):
        k = len(r[0])
        for c in range(6):
            arr[c, i, :k] = r[c]
            arr[c, i, k:] = r[c][-1] if c < 2 else 0.0
        mask[i, :k] = True
    return LegMotion.from_arrays(1 / rate, arr[0], arr[1], arr[2], arr[3], u, arr[4], arr[5]), mask


@pytest.fixture(scope="module")
def demo_cases():
    grid = demo_grid()
    out = {}
    for u in FLOW_SPEEDS_MPS:
        m, mask = grid_motion(grid, u)
        out[u] = (TrueLegModel("rich").wrench(m)[mask], EmpiricalFormula().wrench(m)[mask], m, mask)
    return out


def filtered_noise_variance(sigma, rate_hz=500.0, cutoff_hz=6.0, n=200_000, seed=0):
    """Variance of the load cell's white noise after the ingest's 6 Hz zero-phase low-pass."""
    sos = signal.butter(4, cutoff_hz, fs=rate_hz, output="sos")
    x = np.random.default_rng(seed).standard_normal(n) * sigma
    return float(np.var(signal.sosfiltfilt(sos, x)[1000:-1000]))


def test_ef_truth_is_exactly_the_ef():
    m, _ = grid_motion(demo_grid()[:6], 0.2, cycles=1)
    np.testing.assert_array_equal(TrueLegModel("ef").wrench(m), EmpiricalFormula().wrench(m))


def test_ef_captures_the_trend_of_the_rich_truth(demo_cases):
    for u, (truth, ef, _, _) in demo_cases.items():
        r2 = 1 - ((truth - ef) ** 2).sum(0) / ((truth - truth.mean(0)) ** 2).sum(0)
        # with the rotating-plate added mass (m_a omega v_t, which the EF lacks) the EF's R^2 is
        # 0.53-0.76 (fy), 0.46-0.71 (fz), 0.63-0.86 (tx) over 0-0.3 m/s: still the trend
        assert r2[1] >= 0.45 and r2[2] >= 0.4, (u, r2)
        assert r2[3] >= 0.55, (u, r2)


def test_ef_misses_by_far_more_than_the_filtered_noise(demo_cases):
    lc = LoadCellSettings()
    var_f = filtered_noise_variance(lc.noise_n, lc.rate_hz)
    var_t = filtered_noise_variance(lc.noise_nm, lc.rate_hz)
    for u, (truth, ef, _, _) in demo_cases.items():
        mse = ((truth - ef) ** 2).mean(0)
        ratio = mse[[1, 2, 3]] / np.array([var_f, var_f, var_t])
        assert (ratio >= 5).all(), (u, ratio)
        # the miss is systematic: a refit of the EF's own two coefficients explains most of it
        # (the EF's shape is right), but far from all of it (the truth is richer)
        r2_refit = _refit_r2(demo_cases[u])
        assert 0.75 < r2_refit < 0.995, (u, r2_refit)


def _refit_r2(case):
    from workbench.hydro.ef import EFParams

    truth, _, m, mask = case
    drag = EmpiricalFormula(EFParams(added_mass_factor=0.0, m_web_kg=0.0)).wrench(m)[mask][:, 1]
    inertia = EmpiricalFormula(EFParams(c_r=0.0)).wrench(m)[mask][:, 1]
    x = np.stack([drag, inertia, np.ones_like(drag)], axis=1)
    coef, *_ = np.linalg.lstsq(x, truth[:, 1], rcond=None)
    y = truth[:, 1]
    return 1 - ((y - x @ coef) ** 2).sum() / ((y - y.mean()) ** 2).sum()


def test_magnitudes_are_those_of_the_field_notes(demo_cases):
    for u, (truth, *_) in demo_cases.items():
        rms = np.sqrt((truth**2).mean(0))
        assert 0.05 < rms[1] < 0.5 and 0.05 < rms[2] < 0.5, (u, rms)  # leg forces 0.02-0.5 N
        assert rms[0] < 0.2 * rms[1]  # the lateral force is small
        assert 0.005 < rms[3] < 0.1  # torques: forces x 0.1-0.2 m arms
        assert np.abs(truth[:, :3]).max() < 3.0


def test_rich_truth_has_weight_buoyancy_and_lag():
    p = TruthSettings()
    m, _ = grid_motion(demo_grid()[:1], 0.0, cycles=1)
    still = LegMotion.from_arrays(0.01, np.full(50, -45.0), np.full(50, 0.0), 0.0, 0.0, 0.0, 0.0, 0.0)
    w = TrueLegModel("rich").wrench(still)[0]
    net = ((p.rho_kgpm3 * (p.web_volume_m3 + p.thigh_volume_m3 + p.calf_volume_m3)
            - p.web_mass_kg - p.thigh_mass_kg - p.calf_mass_kg) * p.gravity_mps2)
    np.testing.assert_allclose(w[:, 2], net, atol=1e-12)  # at rest in still water: only weight and buoyancy
    assert abs(w[0, 3]) > 1e-4  # ... at the leg's centre of gravity, off the hip: a torque
    # the circulatory force alone (no inertia): the lag delays it and cuts its amplitude (Theodorsen-like)
    circ = dict(added_mass_coeff=0.0, web_mass_kg=0.0, link_diameter_m=0.0, thigh_mass_kg=0.0, calf_mass_kg=0.0)
    lagged = TrueLegModel("rich", TruthSettings(**circ)).wrench(m)[0, :, 1]
    quasi = TrueLegModel("rich", TruthSettings(lag="none", **circ)).wrench(m)[0, :, 1]
    a, b = lagged - lagged.mean(), quasi - quasi.mean()
    best = max(range(0, 30), key=lambda k: np.dot(a[k:], b[: len(b) - k]))
    assert 2 <= best <= 25  # 15 ms - 0.2 s at 130 Hz
    assert 0.5 < a.std() / b.std() < 0.95


def test_first_order_lag_matches_the_exponential():
    u = np.ones((1, 200, 1))
    u[:, 0] = 0.0
    y = first_order_lag(u, np.full((1, 200), 5.0), 0.01)[0, :, 0]
    t = np.arange(200) * 0.01
    # a unit step at the first step (input ramps over it) against the analytic response
    np.testing.assert_allclose(y[20:], 1 - np.exp(-5.0 * (t[20:] - 0.005)), atol=2e-3)


def test_rows_do_not_depend_on_their_batch():
    grid = demo_grid()
    m, _ = grid_motion([grid[0], grid[5]], 0.1, cycles=2)
    alone, _ = grid_motion([grid[0]], 0.1, cycles=2)
    both = TrueLegModel("rich").wrench(m)
    one = TrueLegModel("rich").wrench(alone)
    np.testing.assert_allclose(both[0, : one.shape[1]], one[0], rtol=0, atol=1e-12)


def test_model_describes_itself_and_rejects_bad_settings():
    json.dumps(TrueLegModel("rich").describe())
    with pytest.raises(ModelError):
        TrueLegModel("nonsense")
    with pytest.raises(ModelError):
        TrueLegModel("rich", TruthSettings(lag="later"))
    m, _ = grid_motion(demo_grid()[:2], 0.2, cycles=1)
    for lag in ("first_order", "none"):
        w = TrueLegModel("rich", TruthSettings(lag=lag)).wrench(m)
        assert np.isfinite(w).all()
