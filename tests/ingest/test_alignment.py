"""Clock alignment and resampling against planted ground truth (offset, drift, forces, angles)."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from ingest_fixtures import PARAMS, RunPlan, wrench_truth

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.hydro.motion import JointSinusoid
from workbench.ingest import ingest_campaign
from workbench.ingest.clock import align_clock

PLANTS = [  # (offset_s, drift_ppm): large and negative offsets, fast and slow device clocks
    (37.25, 80.0),
    (-5.0, -150.0),
    (1234.5, 20.0),
    (0.003, -40.0),
]


@pytest.mark.parametrize("form", ["csv", "bin", "mcap"])
def test_planted_offset_and_drift_recovered_within_a_millisecond(campaign, form):
    plans = [RunPlan(f"r{i}", form=form, cycles=10, offset_s=o, drift_ppm=d, seed=i)
             for i, (o, d) in enumerate(PLANTS)]
    result = ingest_campaign(campaign(plans))
    for plan, q in zip(plans, result.quality["runs"], strict=True):
        truth = plan.truth()
        d_off = q["clock_offset_ms"] - truth["offset_ms"]
        d_drift = (q["clock_drift_ppm"] - truth["drift_ppm"]) * 1e-6 * 1e3  # ms per second of run
        worst = max(abs(d_off + d_drift * t) for t in np.linspace(0, q["duration_s"], 50))
        assert worst < 1.0, (plan.id, q["clock_offset_ms"], truth, q["clock_drift_ppm"])
        assert q["edges_paired"] == 21  # a pulse per second over 20 s, and the start


def test_fit_is_exact_on_exact_edges():
    # device samples fast enough that midpoints are exact: the line must come back to round-off
    t_c = np.arange(0, 30, 0.01)
    sync = (((t_c - 2.0) % 1.0) < 0.1) & (t_c >= 2.0)
    t_d = 5.0 + (1 + 250e-6) * np.arange(-1, 31, 1e-5)
    idx = np.searchsorted(t_c, (t_d - 5.0) / (1 + 250e-6), side="right") - 1  # the line holds its level
    s_d = np.where(idx >= 0, sync[np.clip(idx, 0, None)], False)
    fit = align_clock(t_c, sync.astype(int), t_d, s_d.astype(int))
    assert fit.drift * 1e6 == pytest.approx(250.0, abs=0.5)
    assert fit.offset_s == pytest.approx(5.0 + 250e-6 * 2.0, abs=2e-5)


@pytest.mark.parametrize("form", ["csv", "bin", "mcap"])
def test_forces_land_on_the_right_controller_ticks(campaign, form):
    plan = RunPlan("r1", form=form, cycles=10, offset_s=-12.0, drift_ppm=120.0)
    frame = ingest_campaign(campaign([plan])).frame
    t = frame["time_s"].to_numpy()
    truth = wrench_truth(np.clip(t, 0, 20), plan.flow_speed, plan.params["frequency_hz"])
    got = frame.select(list(WRENCH_CHANNELS)).to_numpy()
    inner = (t > 0.3) & (t < 19.7)  # away from the kinks where the motion starts and stops
    err = np.abs(got - truth)[inner].max(axis=0)
    amp = np.abs(truth).max(axis=0)
    # a 1 ms misalignment of the 0.3 N, 0.5 Hz fy signal alone would be ~1 mN
    assert err[1] < 1e-3 and np.all(err <= 0.01 * amp + 2e-4), err


def test_time_zero_is_the_first_trigger_edge_and_rest_is_kept(campaign):
    plan = RunPlan("r1", rest_s=2.0)
    frame = ingest_campaign(campaign([plan])).frame
    t = frame["time_s"].to_numpy()
    assert np.any(t == 0.0)
    assert t[0] == pytest.approx(-2.0, abs=0.02)      # the 2 s of rest before the run
    rest = frame.filter(pl.col("time_s") < 0)
    th0, tk0, *_ = JointSinusoid.from_params(PARAMS).evaluate(np.array([0.0]))
    np.testing.assert_allclose(rest["theta_h_deg"], th0[0])
    np.testing.assert_allclose(rest["omega_h_dps"].to_numpy()[:-5], 0.0, atol=1e-9)
    np.testing.assert_allclose(rest.select(list(WRENCH_CHANNELS)).to_numpy()[20:-20],
                               np.broadcast_to(wrench_truth(np.zeros(1), 0.1), (rest.height - 40, 6)), atol=2e-4)


def test_rest_stretch_is_capped(campaign):
    frame = ingest_campaign(campaign([RunPlan("r1", rest_s=3.0)]), params={"max_rest_s": 1.0}).frame
    assert frame["time_s"].min() >= -1.0


def test_motion_before_the_first_edge_drops_the_rest_stretch(campaign):
    root = campaign([RunPlan("r1")])
    path = root / "runs/r1.motion.csv"
    df = pl.read_csv(path)
    df = df.with_columns(pl.when(pl.int_range(pl.len()) < 20).then(pl.col("hfe_cmd_deg") + 5.0)
                         .otherwise(pl.col("hfe_cmd_deg")).alias("hfe_cmd_deg"))
    df.write_csv(path, float_precision=None)
    result = ingest_campaign(root)
    assert result.frame["time_s"].min() == 0.0
    assert "moving_before_start" in result.quality["runs"][0]["flags"]


def test_angular_velocities_match_the_analytic_rates(campaign):
    plan = RunPlan("r1", cycles=6, params={**PARAMS, "frequency_hz": 0.6})
    frame = ingest_campaign(campaign([plan])).frame
    t = frame["time_s"].to_numpy()
    inner = (t > 0.2) & (t < 6 / 0.6 - 0.2)
    _, _, wh, wk, *_ = JointSinusoid.from_params(plan.params).evaluate(t[inner])
    np.testing.assert_allclose(frame["omega_h_dps"].to_numpy()[inner], wh, atol=0.005 * np.abs(wh).max())
    np.testing.assert_allclose(frame["omega_k_dps"].to_numpy()[inner], wk, atol=0.005 * np.abs(wk).max())


def test_measured_angles_are_used_when_the_log_has_them(campaign):
    result = ingest_campaign(campaign([RunPlan("r1")], feedback=True))
    assert result.quality["angle_source"] == "measured"
    frame = result.frame.filter(pl.col("time_s").is_between(0.5, 7.5))
    th, *_ = JointSinusoid.from_params(PARAMS).evaluate(frame["time_s"].to_numpy())
    np.testing.assert_allclose(frame["theta_h_deg"].to_numpy(), th - 1.0, atol=0.05)


def test_towing_run_gives_position_speed_and_forces_on_the_carriage_ticks(campaign):
    plan = RunPlan("t1", flow_speed=0.25)
    result = ingest_campaign(campaign([plan], facility="towing_tank", name="tow"))
    f = result.frame
    assert {"position_m", "speed_mps", "heading"} <= set(f.columns)
    assert not {"theta_h_deg", "omega_h_dps"} & set(f.columns)
    mid = f.filter(pl.col("time_s").is_between(1.0, 7.0))
    np.testing.assert_allclose(mid["speed_mps"], 0.25, atol=2e-3)
    assert f["heading"].unique().to_list() == ["forward"]
    assert result.quality["angle_source"] is None
