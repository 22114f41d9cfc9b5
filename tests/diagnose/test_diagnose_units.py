"""Pieces of the diagnosis on their own: split, library, least squares, filters, evidence."""

import numpy as np
import polars as pl
import pytest

from workbench.diagnose import lsq
from workbench.diagnose.data import DataSettings, heldout_mask, prepare
from workbench.diagnose.effects.crosstalk import LoadcellCrosstalk
from workbench.diagnose.effects.fluid import AddedMassError, DragCoefficientError, LinkDrag
from workbench.diagnose.effects.resonance import resonance_filter
from workbench.diagnose.effects.servo import ServoLag, lag_filter
from workbench.diagnose.evidence import EvidenceSettings, RunResidual, peaks
from workbench.diagnose.flowterms import LegKinematics, first_order_lag
from workbench.diagnose.library import EffectLibrary, default_library
from workbench.diagnose.loop import DiagnoseSettings
from workbench.errors import ModelError, ParamsError
from workbench.hydro.ef import EFParams, EmpiricalFormula
from workbench.hydro.motion import JointSinusoid, LegMotion, RunMotion


def _run(run_id, params, flow):
    t = np.arange(0, 4, 1 / 65)
    m = JointSinusoid.from_params(params).motion(t, flow)
    return RunMotion("c", run_id, flow, params, False, t, m, np.zeros((len(t), 6)))


def _params(i):
    return {"theta_h_min_deg": -10.0 * i, "theta_h_max_deg": -100.0, "theta_k_min_deg": 80.0,
            "theta_k_max_deg": -20.0 - i, "frequency_hz": 0.3 + 0.05 * (i % 4), "phi_rad": 1.0, "alpha_rad": 0.0}


def test_split_keeps_parameter_sets_together_and_survives_remeasuring():
    runs = [_run(f"r{i}{u}", _params(i), u) for i in range(20) for u in (0.0, 0.1, 0.2)]
    held = heldout_mask(runs, 0.3)
    by_set = {}
    for r, h in zip(runs, held, strict=False):
        by_set.setdefault(r.params["theta_h_min_deg"], set()).add(bool(h))
    assert all(len(v) == 1 for v in by_set.values())          # all speeds of a set on one side
    assert 0 < held.sum() < len(runs)
    # re-measured: other run ids, other order, tiny parameter noise -> the same sets held out
    again = [_run(f"x{k}", {p: v + 1e-6 for p, v in r.params.items()}, r.flow_speed_mps)
             for k, r in enumerate(reversed(runs))]
    held2 = heldout_mask(again, 0.3)
    assert {r.params["theta_h_min_deg"] for r, h in zip(runs, held, strict=False) if h} == \
        {round(r.params["theta_h_min_deg"], 3) for r, h in zip(again, held2, strict=False) if h}


def test_split_cover_holds_out_every_shared_gait_frequency_and_keeps_one_for_training():
    """``split_cover``: each gait frequency of two or more sets gets a held-out set and keeps a training one."""
    # four gait frequencies, three sets each (the sets' other parameters differ)
    runs = [_run(f"r{i}{u}", dict(_params(i), frequency_hz=0.3 + 0.1 * (i // 3)), u)
            for i in range(12) for u in (0.0, 0.1, 0.2)]
    plain = heldout_mask(runs, 0.3)
    held = heldout_mask(runs, 0.3, cover="frequency_hz")
    sides: dict[float, set] = {}
    for r, h in zip(runs, held, strict=True):
        sides.setdefault(round(r.params["frequency_hz"], 3), set()).add(bool(h))
    assert all(v == {True, False} for v in sides.values()), sides
    plain_sides: dict[float, set] = {}
    for r, h in zip(runs, plain, strict=True):
        plain_sides.setdefault(round(r.params["frequency_hz"], 3), set()).add(bool(h))
    assert any(v != {True, False} for v in plain_sides.values())    # the hash alone left a frequency uncovered
    # sets the hash holds out stay held out (only additions, and one release where a frequency was all held)
    assert held.sum() >= plain.sum() - len(sides)
    again = [_run(f"x{k}", dict(r.params), r.flow_speed_mps) for k, r in enumerate(reversed(runs))]
    assert list(reversed(heldout_mask(again, 0.3, cover="frequency_hz"))) == list(held)


def test_a_split_cover_that_is_no_motion_parameter_is_a_params_error_naming_the_key(tmp_path):
    from workbench.diagnose.loop_settings import DiagnoseSettings
    from workbench.errors import ParamsError

    with pytest.raises(ParamsError, match=r"split_cover 'frequency' is not a motion parameter.*frequency_hz"):
        DiagnoseSettings.from_mapping({"data": {"split_cover": "frequency"}}, path="pipelines/diagnose.yaml")
    assert DiagnoseSettings.from_mapping({"data": {"split_cover": "frequency_hz"}}).data.split_cover == "frequency_hz"


def test_library_composes_and_names_its_terms():
    lib = AddedMassError() + DragCoefficientError() + LinkDrag()
    assert isinstance(lib, EffectLibrary)
    assert lib.names() == ["added_mass_error", "drag_coefficient_error", "link_drag"]
    names = lib.get_feature_names()
    assert any(n.startswith("added_mass_error.delta_kg") and "a_n" in n for n in names)
    assert len(default_library()) == 22
    assert "servo_lag.tau_s (searched)" in " ".join(default_library().get_feature_names())
    with pytest.raises(ModelError):
        lib + AddedMassError()


def test_drag_column_is_the_efs_own_drag_per_unit_coefficient():
    t = np.arange(0, 3, 1 / 65)
    m = JointSinusoid.from_params(_params(2)).motion(t, 0.2)
    extra = EmpiricalFormula(EFParams(c_r=0.7 + 0.3)).wrench(m) - EmpiricalFormula().wrench(m)
    assert np.allclose(extra, 0.3 * LegKinematics(m).drag_unit(), atol=1e-12)
    inertia = EmpiricalFormula(EFParams(m_web_kg=0.06)).wrench(m) - EmpiricalFormula().wrench(m)
    assert np.allclose(inertia, 0.05 * LegKinematics(m).added_mass_unit(), atol=1e-10)


def test_lags_follow_the_continuous_first_order_response():
    dt, tau, f = 1 / 65, 0.05, 0.6
    t = np.arange(0, 10, dt)
    w = 2 * np.pi * f
    exact = (np.sin(w * t) - w * tau * np.cos(w * t)) / (1 + (w * tau) ** 2)
    got = lag_filter(np.sin(w * t)[None], tau, dt)[0]
    assert np.abs(got - exact)[200:].max() < 5e-4
    got2 = first_order_lag(np.sin(w * t)[None], 1 / tau, dt)[0]
    assert np.abs(got2 - exact)[200:].max() < 5e-4


def test_resonance_filter_has_the_modes_gain_and_phase():
    dt, fn, z, f = 1 / 65, 4.0, 0.1, 3.0
    t = np.arange(0, 30, dt)
    y = resonance_filter(np.sin(2 * np.pi * f * t)[:, None], dt, fn, z, axis=0)[:, 0]
    h = 1 / (1 - (f / fn) ** 2 + 2j * z * f / fn)
    ref = np.abs(h) * np.sin(2 * np.pi * f * t + np.angle(h))
    assert np.abs(y - ref)[len(t) // 2:].max() < 0.02 * np.abs(h)


def test_servo_lag_transform_shifts_the_motion_by_its_phase():
    t = np.arange(0, 8, 1 / 65)
    m = JointSinusoid(10, -100, 80, -20, 0.5, 1.0).motion(t, 0.1)
    lagged = ServoLag().transform_motion(m, {"tau_s": 0.04})
    w = 2 * np.pi * 0.5
    amp = np.ptp(lagged.theta_h_deg[0, 300:]) / np.ptp(m.theta_h_deg[0, 300:])
    assert amp == pytest.approx(1 / np.sqrt(1 + (w * 0.04) ** 2), rel=2e-3)


@pytest.mark.parametrize("dead_s, lag_s", [(0.06, 0.0), (0.01, 0.04), (0.025, 0.025)])
def test_servo_lag_with_a_dead_time_matches_the_servos_response(dead_s, lag_s):
    """Dead time plus first-order lag: at each frequency gain 1/|1 + j w lag| and phase w dead + atan(w lag)."""
    dt = 1 / 65
    t = np.arange(0, 12, dt)
    tau = dead_s + lag_s
    nl = {"tau_s": tau, "dead_share": dead_s / tau}
    assert ServoLag().canonical_params({}, nl, {})[0]["dead_s"] == pytest.approx(dead_s)
    for f in (0.4, 2.0, 5.5):  # a stroke's fundamental to the ingest's cutoff
        w = 2 * np.pi * f
        x = np.sin(w * t)[None]
        m = LegMotion(dt, x, x, w * np.cos(w * t)[None], x, np.full_like(x, 0.1))
        y = ServoLag().transform_motion(m, nl).theta_h_deg[0]
        gain, phase = 1 / np.hypot(1, w * lag_s), w * dead_s + np.arctan(w * lag_s)
        ref = gain * np.sin(w * t - phase)
        late = t > 2.0  # past the lag's start from rest
        # the lag's first-order hold is exact for an input linear between ticks: 2 % at 5.5 Hz on 65 Hz ticks
        assert np.abs(y - ref)[late].max() < 0.004 * f, (f, np.abs(y - ref)[late].max())
        if dead_s and f > 1:  # a first-order lag of the same tau is far off in the harmonics
            lag_only = np.sin(w * t - np.arctan(w * tau)) / np.hypot(1, w * tau)
            assert np.abs(lag_only - ref)[late].max() > 0.01 * f
    # a saved model from before the dead time (``{"tau_s": x}``) is a pure first-order lag
    lagged = ServoLag().transform_motion(m, {"tau_s": 0.04}).theta_h_deg[0]
    assert np.allclose(lagged, lag_filter(m.theta_h_deg[0], 0.04, dt))
    assert ServoLag(shapes="lag").search[0].name == "tau_s" and len(ServoLag(shapes="lag").search) == 1
    with pytest.raises(ModelError, match="shapes"):
        ServoLag(shapes="dead")


def test_weighted_least_squares_with_per_run_columns_matches_a_dense_solve():
    rng = np.random.default_rng(0)
    nb, k, m, runs = 40, 3, 2, 8
    g_list, b_list = [], []
    xs, ys, run_of = [], [], []
    theta = np.array([1.0, -2.0, 0.5])
    loc = rng.normal(size=(runs, m))
    run = np.repeat(np.arange(runs), nb // runs)
    for i in range(nb):
        x = rng.normal(size=(10, k + m))
        y = x[:, :k] @ theta + x[:, k:] @ loc[run[i]] + 0.01 * rng.normal(size=10)
        xs.append(x)
        ys.append(y)
        run_of.append(run[i])
    for c in range(6):
        scale = 1.0 if c == 1 else 0.0   # one channel holds everything
        g_list.append(np.array([scale * x.T @ x for x in xs]))
        b_list.append(np.array([scale * x.T @ y for x, y in zip(xs, ys, strict=False)]))
    yy = np.zeros((nb, 6))
    yy[:, 1] = [y @ y for y in ys]
    gr = lsq.Grams(["a", "b", "c"], [np.arange(k)] * 6, g_list, b_list, yy, np.full(nb, 10), run,
                   np.zeros(nb, int), np.zeros(nb, bool), ["l1", "l2"])
    f = lsq.fit(gr, np.ones(6))
    # dense reference: shared columns + one block of local columns per run
    big = np.zeros((nb * 10, k + runs * m))
    for i, x in enumerate(xs):
        big[i * 10:(i + 1) * 10, :k] = x[:, :k]
        big[i * 10:(i + 1) * 10, k + run[i] * m:k + (run[i] + 1) * m] = x[:, k:]
    ref = np.linalg.lstsq(big, np.concatenate(ys), rcond=None)[0]
    assert np.allclose(f.theta, ref[:k], atol=1e-8)
    assert np.allclose(f.local[3], ref[k + 3 * m:k + 4 * m], atol=1e-8)
    assert np.all(np.sqrt(np.diag(f.cov)) < 0.01)


def _residual_runs(line_hz=None, n=12, seed=0):
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        t = np.arange(-1, 10, 1 / 65)
        e = rng.normal(size=(len(t), 6)) * 0.002
        if line_hz:
            e[:, 1] += 0.004 * np.sin(2 * np.pi * line_hz * t + rng.uniform(0, 6))
        fit = (t > 0.5) & (t < 9.5)
        z = np.zeros_like(e)
        out.append(RunResidual(f"r{i}", i, False, 0.1, 0.3 + 0.1 * (i % 4), 1 / 65, t, fit, t < 0, t, t, t, t, e, z))
    return out


def test_a_line_locked_to_nothing_is_found_and_noise_has_none():
    found = peaks(_residual_runs(line_hz=2.7), EvidenceSettings())
    assert len(found) == 1 and found[0].frequency_hz == pytest.approx(2.7, abs=0.03)
    assert found[0].channels == ["fy_n"]
    assert sum(len(peaks(_residual_runs(seed=s), EvidenceSettings())) for s in range(5)) == 0


def test_crosstalk_fits_only_identifiable_entries():
    rng = np.random.default_rng(1)
    p = np.zeros((2, 50, 6))
    p[..., 1] = rng.normal(size=(2, 50))
    p[..., 2] = rng.normal(size=(2, 50))
    p[..., 5] = 0.02 * p[..., 1]                       # tz proportional to fy, as in the EF
    xt = LoadcellCrosstalk().configured(p, np.ones((2, 50), bool))
    sources = {j for _, j in xt.pairs}
    assert sources == {1, 2}                            # fx never excited, tz an alias of fy
    assert "x_fx_tz" in xt.aliases["x_fx_fy"]


def test_settings_reject_unknown_keys_and_the_pipeline_file_loads():
    from workbench.project import load_params

    s = DiagnoseSettings.from_mapping(load_params("pipelines/diagnose.yaml", "diagnose"))
    assert s.selection.alpha == 0.01
    with pytest.raises(ParamsError, match=r"diagnose\.selection\.alpha_typo: unknown setting .*did you mean 'alpha'"):
        DiagnoseSettings.from_mapping({"selection": {"alpha_typo": 1}})
    with pytest.raises(ParamsError, match=r"diagnose\.nonsense"):
        DiagnoseSettings.from_mapping({"nonsense": 1})


def test_the_shipped_pipeline_file_holds_the_code_defaults():
    """`workbench diagnose` run outside the project (no pipelines/diagnose.yaml there) diagnoses as the demo does.

    Before, the code analysed all runs and the file at most 96: on the demo campaign's 192 runs the
    two claimed different effects (docs/diagnose.md, "What is weak").
    """
    from workbench.project import load_params

    shipped = DiagnoseSettings.from_mapping(load_params("pipelines/diagnose.yaml", "diagnose"))
    assert shipped == DiagnoseSettings()
    assert DiagnoseSettings().data.max_runs == 96


def test_a_frame_without_tunnel_columns_is_refused():
    frame = pl.DataFrame({"run_id": ["a"], "time_s": [0.0]})
    with pytest.raises(Exception, match="missing column"):
        prepare(frame, DataSettings())


def test_block_sums_match_a_dense_product_channel_by_channel():
    from types import SimpleNamespace

    rng = np.random.default_rng(4)
    b, t = 3, 40
    cols = [rng.normal(size=(b, t, 6)) for _ in range(3)]
    support = [np.ones(6, bool), np.array([0, 0, 1, 1, 1, 0], bool), np.array([1, 0, 0, 0, 0, 0], bool)]
    local = [rng.normal(size=(b, t, 6))]
    design = SimpleNamespace(names=["a", "b", "c"], cols=cols, support=support, base=rng.normal(size=(b, t, 6)),
                             local=local, local_names=["l"])
    rs = SimpleNamespace(shape=(b, t), y=rng.normal(size=(b, t, 6)), heldout=False)
    ticks = np.array([[0, 1, 2, 3, -1], [45, 46, 47, 48, 49], [100, 101, -1, -1, -1]])
    blocks = SimpleNamespace(ticks=ticks, run=np.array([0, 1, 2]), order=np.zeros(3, int))
    gr = lsq.accumulate(design, rs, blocks, ["c", "a", "b"])
    resid = (rs.y - design.base).reshape(b * t, 6)
    for c in range(6):
        names = [n for n in ["c", "a", "b"] if support[["a", "b", "c"].index(n)][c]]
        assert [gr.names[i] for i in gr.chan_cols[c]] == names
        for k, row in enumerate(ticks):
            idx = row[row >= 0]
            x = np.stack([cols[["a", "b", "c"].index(n)].reshape(b * t, 6)[idx, c] for n in names]
                         + [local[0].reshape(b * t, 6)[idx, c]], axis=-1)
            np.testing.assert_allclose(gr.G[c][k], x.T @ x, atol=1e-12)
            np.testing.assert_allclose(gr.b[c][k], x.T @ resid[idx, c], atol=1e-12)


def test_a_campaign_too_small_to_hold_out_a_set_is_a_one_line_data_error(vl_frames):
    """Two runs of one parameter set leave nothing to hold out: a DataError naming the cause, not a traceback."""
    import polars as pl

    from workbench.contract.columns import TUNNEL_MOTION_PARAMS
    from workbench.diagnose.data import DataSettings, prepare
    from workbench.errors import DataError

    frame = vl_frames()
    cols = [c for c in TUNNEL_MOTION_PARAMS if c in frame.columns]
    first = frame.row(0, named=True)
    one_set = frame.filter(pl.all_horizontal([pl.col(c) == first[c] for c in cols]))  # every flow speed of one set
    assert one_set["run_id"].n_unique() >= 2
    with pytest.raises(DataError, match="motion-parameter set"):
        prepare(one_set, DataSettings(), source="tiny.parquet")


def test_reference_noise_is_measured_at_rest_and_shrunk_out_of_the_learned_waveform():
    """The reference's noise must not ride on the corrected model (it biases a mode's damping, hides crosstalk).

    A run at 0.5 Hz: rest, then a strong 2nd harmonic and a weak 9th (4.5 Hz) in white noise of
    a known level. The rest stretch gives the noise's level; the learned waveform keeps the
    strong harmonic, drops most of the noise, and the weak harmonic is shrunk, not inflated.
    """
    from types import SimpleNamespace

    from workbench.diagnose.reference import _basis, _shrunk_fit, noise_psd

    rng = np.random.default_rng(3)
    dt, sigma, f = 1 / 65, 0.01, 0.5
    runs = []
    for _ in range(36):
        t = np.arange(-1.0, 8.0, dt)
        resid = sigma * rng.standard_normal((len(t), 6))
        runs.append(SimpleNamespace(time_s=t, rest=t < 0, resid=resid, dt_s=dt))
    psd = noise_psd(runs)
    level = np.array([psd(nu) for nu in (1.5, 3.0, 4.5)]) / sigma**2
    assert abs(level.mean() - 1) < 0.15 and np.abs(level - 1).max() < 0.45, level
    t = np.arange(0.5, 7.5, dt)
    signal = np.zeros((len(t), 6))
    signal[:, 0] = 0.2 * np.cos(2 * np.pi * 2 * f * t)
    signal[:, 1] = 0.3 * sigma * np.sin(2 * np.pi * 9 * f * t)
    e = signal + sigma * rng.standard_normal(signal.shape)
    x = _basis(t, f, 12, 3, (t[0], t[-1]))
    plain = x @ _shrunk_fit(x, e, f, 12, 4, None)
    shrunk = x @ _shrunk_fit(x, e, f, 12, 4, psd)
    err_plain = ((plain - signal) ** 2).mean(axis=0)
    err_shrunk = ((shrunk - signal) ** 2).mean(axis=0)
    # the strong harmonic is kept (within 1 %), the noise carried into the waveform falls
    assert np.abs(shrunk[:, 0] - signal[:, 0]).max() < 0.2 * 0.05
    assert (err_shrunk[2:] < 0.5 * err_plain[2:]).all(), (err_shrunk, err_plain)
    # a weak harmonic is shrunk towards zero, never amplified
    amp = 2 * np.abs(np.mean(shrunk[:, 1] * np.sin(2 * np.pi * 9 * f * t)))
    assert amp < 0.3 * sigma * 1.2


def test_a_mode_filters_the_design_part_by_part_as_it_would_whole():
    """With a mode claimed the design is filtered one part at a time and cached per value (the base, each
    force effect's terms); a search moving a force effect's value, then the mode's, must get the design that
    filtering the unfiltered design whole gives, and fits the same block sums as comparing it afresh."""
    from types import SimpleNamespace

    from workbench.diagnose.chain import Active, Configuration, build_design, compare_filter

    t = np.arange(0, 6, 1 / 65)
    th, tk, wh, wk, ah, ak = JointSinusoid(-10.0, -100.0, 80.0, -40.0, 0.5, 2.0, 0.0).evaluate(t)
    motion = LegMotion.from_arrays(1 / 65, th, tk, wh, wk, np.full_like(th, 0.2), ah, ak)
    batch = SimpleNamespace(motion=motion, dt_s=1 / 65,
                            time_s=np.broadcast_to(np.arange(motion.shape[1]) / 65, motion.shape))
    lib = {e.name: e for e in default_library()}
    model = EmpiricalFormula()
    cache: dict = {}
    steps = [(0.5, 4.5), (1.5, 4.5), (4.0, 4.5), (1.5, 4.5), (1.5, 3.0), (1.5, 6.0)]
    for tau, f_n in steps:
        force = [Active(lib["added_mass_error"], {}), Active(lib["circulatory_lag"], {"tau_chords": tau}),
                 Active(lib["link_inertia"], {})]
        nl = {"f_n_hz": f_n, "zeta": 0.08}
        config = Configuration([*force, Active(lib["structural_resonance"], nl)])
        d = build_design(model, batch, config, cache=cache)
        plain = build_design(model, batch, Configuration(force))  # unfiltered, no cache
        whole = lib["structural_resonance"].filter_wrench(np.stack([plain.base, *plain.cols]), 1 / 65, nl)
        assert d.names == plain.names
        scale = np.abs(whole).max()
        np.testing.assert_allclose(d.base, whole[0], atol=1e-9 * scale)
        for c, w in zip(d.cols, whole[1:], strict=True):
            np.testing.assert_allclose(c, w, atol=1e-9 * np.abs(w).max())
        compare = compare_filter(config, 1 / 65)
        assert set(d.compared) == set(d.names)
        for n, c in zip(d.names, d.cols, strict=True):
            np.testing.assert_allclose(d.compared[n], compare(c), atol=1e-9 * np.abs(c).max())
    # the block sums through the cached compared columns equal those compared afresh
    d.compare = compare
    rng = np.random.default_rng(0)
    rs = SimpleNamespace(shape=d.base.shape[:2], y=d.base + rng.normal(size=d.base.shape), heldout=False)
    ticks = np.arange(d.base.shape[1])[None, :]
    blocks = SimpleNamespace(ticks=ticks, run=np.array([0]), order=np.zeros(1, int))
    cached = lsq.accumulate(d, rs, blocks)
    d.compared = {}
    fresh = lsq.accumulate(d, rs, blocks)
    for c in range(6):
        np.testing.assert_allclose(cached.G[c], fresh.G[c], rtol=1e-12, atol=1e-12 * np.abs(fresh.G[c]).max())
        np.testing.assert_allclose(cached.b[c], fresh.b[c], rtol=1e-12, atol=1e-12 * np.abs(fresh.b[c]).max())


def test_crosstalk_makes_the_compared_misfit_columns_from_the_compared_residual():
    """Beside a mode the crosstalk's projection is fitted through the inverse mode; the other channels' residuals
    times each run's flow powers are made from the compared residual (6 series) instead of comparing all 90."""
    from types import SimpleNamespace

    from workbench.diagnose.effects.crosstalk import _others
    from workbench.diagnose.effects.resonance import inverse_mode

    rng = np.random.default_rng(1)
    resid = rng.normal(size=(4, 300, 6)).cumsum(axis=1)
    rs = SimpleNamespace(flow=np.array([0.0, 0.1, 0.2, np.nan]))

    def compare(x):
        return inverse_mode(x, 1 / 65, 4.5, 0.05, axis=-2)

    for i, (slow, fast) in enumerate(zip([compare(o) for o in _others(rs, resid, 2)], _others(rs, compare(resid), 2),
                                         strict=True)):
        assert slow.shape == (4, 300, 15)
        np.testing.assert_allclose(fast, slow, atol=1e-12 * np.abs(slow).max())
        # channel i is not among its own others; the run of unknown flow has only its zeroth power
        np.testing.assert_allclose(fast[..., :5], compare(np.delete(resid, i, axis=-1)), atol=1e-12 * np.abs(slow).max())
        assert not fast[3, :, 5:].any()
