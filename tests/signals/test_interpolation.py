"""Flow-speed interpolation reproduces a known quadratic and marks what it made."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.hydro.motion import JointSinusoid
from workbench.signals.interpolation import (
    InterpolationSettings,
    interpolate_flow_speeds,
    interpolate_with_report,
)

P1 = dict(theta_h_min_deg=10.0, theta_h_max_deg=-100.0, theta_k_min_deg=80.0, theta_k_max_deg=-20.0,
          frequency_hz=0.5, phi_rad=1.0472, alpha_rad=0.0)
P2 = {**P1, "theta_h_min_deg": -30.0, "frequency_hz": 0.4}


def coefficients(t, f):
    """Known per-tick quadratic coefficients (band-limited well below 6 Hz)."""
    w = 2 * np.pi * f
    a = np.stack([0.1 * np.sin(w * t + k) for k in range(6)], axis=1)
    b = np.stack([0.3 * np.cos(w * t + k) for k in range(6)], axis=1)
    c = np.stack([2.0 * np.sin(2 * w * t + k) ** 2 for k in range(6)], axis=1)
    return a, b, c


def run_frame(run_id, v, p, t0=-1.0, t1=16.0, dt=1 / 65):
    t = np.arange(t0, t1, dt)
    a, b, c = coefficients(t, p["frequency_hz"])
    w = a + b * v + c * v ** 2
    th, tk, wh, wk, *_ = JointSinusoid.from_params(p).evaluate(np.clip(t, 0, None))
    cols = {"campaign_id": "c", "run_id": run_id, "time_s": t, "flow_speed_mps": v, "theta_h_deg": th,
            "theta_k_deg": tk, "omega_h_dps": wh, "omega_k_dps": wk,
            **{ch: w[:, k] for k, ch in enumerate(WRENCH_CHANNELS)}, "interpolated": False,
            **{k: float(x) for k, x in p.items()}, "cycles": 8}
    return pl.DataFrame(cols).with_columns(pl.col("cycles").cast(pl.Int32))


@pytest.fixture
def frame():
    runs = []
    for i, v in enumerate((0.0, 0.1, 0.2, 0.3)):
        runs.append(run_frame(f"a{i}", v, P1, t1=16.0 + 0.3 * i))  # runs of slightly different length
        runs.append(run_frame(f"b{i}", v, P2))
    runs.append(run_frame("lonely", 0.1, {**P1, "phi_rad": 2.0}))  # measured at one speed only
    return pl.concat(runs)


def test_reproduces_a_known_quadratic(frame):
    out = interpolate_flow_speeds(frame)
    made = out.filter(pl.col("interpolated"))
    assert sorted(made["run_id"].unique()) == ["a0@v0.050", "a0@v0.150", "a0@v0.250",
                                               "b0@v0.050", "b0@v0.150", "b0@v0.250"]
    for run_id, p in (("a0@v0.150", P1), ("b0@v0.250", P2)):
        r = made.filter(pl.col("run_id") == run_id)
        v = r["flow_speed_mps"][0]
        t = r["time_s"].to_numpy()
        a, b, c = coefficients(t, p["frequency_hz"])
        want = a + b * v + c * v ** 2
        got = r.select(list(WRENCH_CHANNELS)).to_numpy()
        inner = slice(30, -30)  # the low-pass's edge padding
        np.testing.assert_allclose(got[inner], want[inner], atol=2e-3 * np.abs(want).max())
        assert r["frequency_hz"][0] == p["frequency_hz"] and r["theta_h_min_deg"][0] == p["theta_h_min_deg"]
        th, *_ = JointSinusoid.from_params(p).evaluate(np.clip(t, 0, None))
        np.testing.assert_allclose(r["theta_h_deg"], th, atol=1e-9)


def test_common_window_and_measured_rows_unchanged(frame):
    out = interpolate_flow_speeds(frame)
    assert out.filter(~pl.col("interpolated")).equals(frame)
    a = out.filter(pl.col("run_id") == "a0@v0.050")
    assert a["time_s"].min() >= -1.0 and a["time_s"].max() <= 16.0


def test_sets_with_too_few_speeds_are_reported_not_invented(frame):
    _, report = interpolate_with_report(frame, InterpolationSettings())
    assert len(report.skipped_sets) == 1 and report.skipped_sets[0]["runs"] == ["lonely"]
    assert report.made["a0@v0.150"] == ["a0", "a1", "a2", "a3"]


def test_no_extrapolation_by_default(frame):
    out = interpolate_flow_speeds(frame, speeds=(0.35, 0.15))
    assert sorted(out.filter(pl.col("interpolated"))["flow_speed_mps"].unique()) == [0.15]
    out = interpolate_flow_speeds(frame, speeds=(0.35,), extrapolate=True)
    assert out.filter(pl.col("interpolated"))["flow_speed_mps"].unique().to_list() == [0.35]


def test_idempotent_on_its_own_output(frame):
    once = interpolate_flow_speeds(frame)
    twice = interpolate_flow_speeds(once)
    assert twice.equals(once)
