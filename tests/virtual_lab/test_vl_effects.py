"""Each planted effect changes what its definition says, and nothing else."""

import json
import math

import numpy as np
import polars as pl
import pytest

from workbench.errors import WorkbenchError
from workbench.hydro.ef import EmpiricalFormula, web_normal_force_to_wrench
from workbench.hydro.kinematics import DEFAULT_GEOMETRY, leg_state
from workbench.hydro.motion import JointSinusoid
from workbench.virtual_lab.effects import REGISTRY, EffectSpec, describe_all, parse_effect, parse_effects
from workbench.virtual_lab.tunnel import generate_tunnel, truth_model

CANONICAL = {"servo_lag", "added_mass_error", "drag_coefficient_error", "tunnel_blockage", "loadcell_crosstalk",
             "leg_weight_buoyancy", "sensor_drift", "structural_resonance", "flow_unsteadiness", "circulatory_lag",
             "link_drag", "lift", "electrical_pickup"}
RHO, S = 1000.0, 0.06**2
TINY = dict(grid=[{"theta_h_min_deg": -10.0, "theta_k_max_deg": -40.0, "frequency_hz": 0.6, "phi_rad": math.pi / 3}],
            flow_speeds=(0.0, 0.2), cycles=1, seed=5)


def test_registry_holds_every_canonical_effect_with_documentation():
    assert set(REGISTRY) == CANONICAL
    for d in describe_all():
        assert d["stage"] in ("motion", "flow", "force", "reading")
        assert len(d["physics"]) > 40 and d["params"]


def test_parsing_specs():
    e = parse_effect("servo_lag:tau_s=0.03")
    assert e.name == "servo_lag" and e.tau_s == 0.03
    assert parse_effect("servo_lag").tau_s == 0.04  # default
    assert parse_effect(EffectSpec("lift", {"cl": 0.2})).cl == 0.2
    assert parse_effect({"name": "link_drag", "params": {"cd_d_m": 0.02}}).cd_d_m == 0.02
    x = parse_effect("loadcell_crosstalk:x_fx_fy=0.02,x_tz_fz=0.01")
    assert x.values == {"x_fx_fy": 0.02, "x_tz_fz": 0.01}
    assert parse_effect("loadcell_crosstalk").values == {"x_fy_fz": 0.03, "x_fz_fy": 0.02}
    assert parse_effect("sensor_drift:rate_fz_per_s=0.001").values == {"rate_fz_n_per_s": 0.001}
    assert parse_effect("electrical_pickup:channels=fx_n|tz_nm").channels == "fx_n+tz_nm"
    assert parse_effect("leg_weight_buoyancy:net_n=-0.1,arm_m=0.12").spec().spec() == \
        "leg_weight_buoyancy:arm_m=0.12,net_n=-0.1"
    for bad in ("no_such_effect", "servo_lag:tau=1", "servo_lag:tau_s=abc", "servo_lag:tau_s=-1",
                "loadcell_crosstalk:x_fx_fx=0.1", "electrical_pickup:channels=fq_n", "servo_lag:0.1"):
        with pytest.raises(WorkbenchError):
            parse_effect(bad)
    with pytest.raises(WorkbenchError):
        parse_effects(["lift", "lift:cl=0.1"])


# ------------------------------------------------------------------------------ motion
def test_servo_lag_is_a_first_order_lag():
    f, tau, dt = 0.5, 0.05, 0.002
    t = np.arange(0, 10, dt)
    w = 2 * np.pi * f
    cmd = np.stack([30 * np.sin(w * t), 20 * np.cos(w * t)], axis=1)
    rate = np.stack([30 * w * np.cos(w * t), -20 * w * np.sin(w * t)], axis=1)
    acc = np.stack([-30 * w * w * np.sin(w * t), -20 * w * w * np.cos(w * t)], axis=1)
    th, om, al = parse_effect(f"servo_lag:tau_s={tau}").apply_motion(cmd, rate, acc, dt)
    late = (t > 2) & (t < 9.9)  # steady state: gain 1/sqrt(1 + (w tau)^2), phase atan(w tau)
    gain, phase = 1 / math.hypot(1, w * tau), math.atan(w * tau)
    np.testing.assert_allclose(th[late, 0], 30 * gain * np.sin(w * t[late] - phase), atol=0.01)
    np.testing.assert_allclose(om[late], np.gradient(th, dt, axis=0)[late], rtol=0, atol=0.05)
    np.testing.assert_allclose(al[late], np.gradient(om, dt, axis=0)[late], rtol=0, atol=0.5)
    assert th[0, 0] == cmd[0, 0] and om[0, 0] == 0.0  # starts at rest on the first command


# -------------------------------------------------------------------------------- flow
def test_blockage_and_unsteadiness_act_on_the_flow_only_when_it_runs():
    t = np.arange(0, 20, 0.002)
    u = np.full_like(t, 0.2)
    rng = np.random.default_rng(0)
    np.testing.assert_allclose(parse_effect("tunnel_blockage:epsilon=0.1").apply_flow(u, t, rng), 0.2 * math.sqrt(1.1))
    e = parse_effect("flow_unsteadiness:rms_fraction=0.01,tone_hz=2.0,tone_fraction=0.02")
    ue = e.apply_flow(u, t, rng)
    rel = ue / 0.2 - 1
    spec = np.abs(np.fft.rfft(rel))
    freqs = np.fft.rfftfreq(len(t), 0.002)
    above = freqs > 1.0  # the coloured noise lives below its 0.5 Hz corner
    assert freqs[above][np.argmax(spec[above])] == pytest.approx(2.0, abs=0.06)
    assert rel.std() == pytest.approx(math.hypot(0.01, 0.02 / math.sqrt(2)), rel=0.05)  # RMS add in quadrature
    assert (e.apply_flow(np.zeros_like(t), t, rng) == 0).all()


# ------------------------------------------------------------------------------- force
@pytest.fixture(scope="module")
def motion():
    js = JointSinusoid(-10.0, -100.0, 80.0, -40.0, 0.5, math.pi / 3)
    t = np.arange(0, 4, 1 / 200)
    return js.motion(t, 0.2)


def _kin(m):
    ah, ak = m.accelerations_dps2()
    st = leg_state(*(np.radians(x) for x in (m.theta_h_deg, m.theta_k_deg, m.omega_h_dps, m.omega_k_dps, ah, ak)))
    water = np.stack([-m.flow_speed_mps, np.zeros_like(m.flow_speed_mps)], axis=-1)
    rel = water - st.q_vel
    return st, rel


def _delta(spec, m):
    base = EmpiricalFormula().wrench(m)
    return truth_model("ef", {}, parse_effects([spec])).wrench(m) - base


def test_added_mass_error(motion):
    st, _ = _kin(motion)
    a_n = np.einsum("...i,...i", st.q_acc, st.normal)
    np.testing.assert_allclose(_delta("added_mass_error:delta_kg=0.05", motion),
                               web_normal_force_to_wrench(-0.05 * a_n, st, DEFAULT_GEOMETRY), atol=1e-12)


def test_drag_coefficient_error(motion):
    st, rel = _kin(motion)
    v_n = np.einsum("...i,...i", rel, st.normal)
    expect = web_normal_force_to_wrench(0.5 * RHO * S * 0.3 * np.abs(v_n) * v_n, st, DEFAULT_GEOMETRY)
    np.testing.assert_allclose(_delta("drag_coefficient_error:delta_c=0.3", motion), expect, atol=1e-12)


def test_lift(motion):
    st, rel = _kin(motion)
    v_t = np.einsum("...i,...i", rel, st.tangent)
    expect = web_normal_force_to_wrench(0.5 * RHO * S * 0.4 * np.linalg.norm(rel, axis=-1) * v_t, st,
                                        DEFAULT_GEOMETRY)
    np.testing.assert_allclose(_delta("lift:cl=0.4", motion), expect, atol=1e-12)


def test_leg_weight_buoyancy(motion):
    st, _ = _kin(motion)
    d = _delta("leg_weight_buoyancy:net_n=-0.05,arm_m=0.1", motion)
    q3 = np.concatenate([np.full(st.q.shape[:-1] + (1,), DEFAULT_GEOMETRY.web_offset_x_m), st.q], axis=-1)
    norm = np.linalg.norm(q3, axis=-1)
    np.testing.assert_allclose(d[..., 2], -0.05)
    np.testing.assert_allclose(d[..., 3], -0.05 * 0.1 * st.q[..., 0] / norm, atol=1e-15)
    np.testing.assert_allclose(d[..., 4], 0.05 * 0.1 * 0.02 / norm, atol=1e-15)
    assert np.all(d[..., [0, 1, 5]] == 0)


def test_link_drag_is_linear_in_its_coefficient_and_in_plane(motion):
    d1 = _delta("link_drag:cd_d_m=0.01", motion)
    d2 = _delta("link_drag:cd_d_m=0.02", motion)
    np.testing.assert_allclose(d2, 2 * d1, atol=1e-12)
    assert np.all(d1[..., 0] == 0) and np.abs(d1[..., 1]).max() > 1e-3


def test_circulatory_lag_lags_the_drag_along_the_normal(motion):
    st, _ = _kin(motion)
    d = _delta("circulatory_lag:tau_chords=3", motion)
    small = _delta("circulatory_lag:tau_chords=0.001", motion)
    assert np.abs(d[..., 1]).max() > 20 * np.abs(small[..., 1]).max()
    # the change is a force along the web normal at Q: no fx, (fy, fz) parallel to n
    assert np.all(d[..., 0] == 0)
    cross = d[..., 1] * st.normal[..., 1] - d[..., 2] * st.normal[..., 0]
    np.testing.assert_allclose(cross, 0, atol=1e-12)


# ----------------------------------------------------------------------------- reading
def _reading(spec, wrench, dt=0.002):
    t = np.arange(len(wrench)) * dt
    return parse_effect(spec).apply_reading(wrench, t - 1.0, t + 1234.5, dt, np.random.default_rng(0))


def test_crosstalk_mixes_only_the_named_channels():
    w = np.random.default_rng(1).standard_normal((500, 6))
    out = _reading("loadcell_crosstalk:x_fx_fy=0.03,x_tz_fz=-0.02", w)
    np.testing.assert_allclose(out[:, 0], w[:, 0] + 0.03 * w[:, 1])
    np.testing.assert_allclose(out[:, 5], w[:, 5] - 0.02 * w[:, 2])
    np.testing.assert_array_equal(out[:, 1:5], w[:, 1:5])


def test_sensor_drift_from_the_first_edge_on_the_named_channel():
    w = np.zeros((2000, 6))
    out = _reading("sensor_drift:rate_fz_n_per_s=0.002", w)
    t = np.arange(2000) * 0.002 - 1.0
    np.testing.assert_allclose(out[:, 2], 0.002 * np.maximum(t, 0))
    assert np.all(np.delete(out, 2, axis=1) == 0)


def test_structural_resonance_keeps_dc_and_rings_at_its_frequency():
    n, dt = 20000, 0.002
    t = np.arange(n) * dt
    w = np.zeros((n, 6))
    w[:, 1] = 0.3  # constant: unchanged
    w[:, 2] = 0.1 * np.sin(2 * np.pi * 4.0 * t)
    w[:, 3] = 0.01 * np.sin(2 * np.pi * 0.3 * t)
    out = _reading("structural_resonance:f_n_hz=4,zeta=0.1", w)
    np.testing.assert_allclose(out[:, 1], 0.3, atol=1e-9)
    assert np.abs(out[5000:, 2]).max() == pytest.approx(0.1 / (2 * 0.1), rel=0.03)  # gain 1/(2 zeta) at f_n
    assert np.abs(out[5000:, 3]).max() == pytest.approx(0.01, rel=0.02)  # paddling band passes
    assert np.all(out[:, [0, 4, 5]] == 0)


def test_electrical_pickup_adds_a_tone_on_the_listed_channels():
    w = np.zeros((10000, 6))
    out = _reading("electrical_pickup:f_hz=2.7,amplitude_n=0.01,channels=fy_n|tx_nm", w)
    assert np.abs(out[:, 1]).max() == pytest.approx(0.01, rel=1e-3)
    assert np.abs(out[:, 3]).max() == pytest.approx(0.0005, rel=1e-3)
    spec = np.abs(np.fft.rfft(out[:, 1]))
    assert np.fft.rfftfreq(10000, 0.002)[np.argmax(spec)] == pytest.approx(2.7, abs=0.05)
    assert np.all(out[:, [0, 2, 4, 5]] == 0)


# ------------------------------------------------------------------------ whole campaign
@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    return generate_tunnel(tmp_path_factory.mktemp("fx") / "plain", **TINY)


def _files(root):
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted((root / "runs").iterdir())}


def test_a_reading_effect_changes_only_its_channel(plain, tmp_path):
    out = generate_tunnel(tmp_path / "drift", effects=["sensor_drift:rate_fz_n_per_s=0.004"], **TINY)
    a, b = _files(plain), _files(out)
    for name in a:
        if name.endswith(".motion.csv"):
            assert a[name] == b[name]
        else:
            fa, fb = pl.read_csv(a[name]), pl.read_csv(b[name])
            for col in fa.columns:
                same = fa[col].equals(fb[col])
                assert same == (col != "fz_n"), (name, col)
    truth = json.loads((out / "truth.json").read_text())
    assert truth["effects"] == [{"name": "sensor_drift", "params": {"rate_fz_n_per_s": 0.004}}]


def test_motion_and_flow_effects_leave_the_logs_and_still_water_alone(plain, tmp_path):
    out = generate_tunnel(tmp_path / "lag", effects=["servo_lag:tau_s=0.05", "tunnel_blockage:epsilon=0.1"], **TINY)
    a, b = _files(plain), _files(out)
    for name in a:
        if name.endswith(".motion.csv"):
            assert a[name] == b[name]  # the controller logs its commands, not the servo's lag
        else:
            assert a[name] != b[name]  # the servo lag moves every run's force
    # blockage alone: runs in still water (r0001) are untouched
    out2 = generate_tunnel(tmp_path / "blk", effects=["tunnel_blockage:epsilon=0.1"], **TINY)
    c = _files(out2)
    assert c["runs/r0001.loadcell.csv"] == a["runs/r0001.loadcell.csv"]
    assert c["runs/r0002.loadcell.csv"] != a["runs/r0002.loadcell.csv"]


def test_servo_lag_shows_in_the_feedback_columns(tmp_path):
    out = generate_tunnel(tmp_path / "fb", effects=["servo_lag:tau_s=0.06"], feedback=True, **TINY)
    m = pl.read_csv(out / "runs" / "r0002.motion.csv")
    cmd, meas = m["hfe_cmd_deg"].to_numpy(), m["hfe_meas_deg"].to_numpy()
    # the measured angle follows the command about tau later: fit the delay by least squares
    dt = 1 / 65
    lags = np.arange(0, 10)
    err = [np.mean((meas[k:] - cmd[: len(cmd) - k]) ** 2) for k in lags]
    assert lags[int(np.argmin(err))] * dt == pytest.approx(0.06, abs=dt)
