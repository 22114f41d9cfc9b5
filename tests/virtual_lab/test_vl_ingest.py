"""Integration with the virtual lab: campaigns in every form, planted clocks from truth.json."""

from __future__ import annotations

import json

import numpy as np
import polars as pl
import pytest

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.ingest import ingest_campaign
from workbench.signals.interpolation import interpolate_flow_speeds
from workbench.virtual_lab import towing as vl_towing
from workbench.virtual_lab import tunnel as vl_tunnel

GRID = [{"theta_h_min_deg": 10.0, "theta_k_max_deg": -20.0, "frequency_hz": 0.5, "phi_rad": 1.0472},
        {"theta_h_min_deg": -30.0, "theta_k_max_deg": -60.0, "frequency_hz": 0.3, "phi_rad": 2.0}]


def clock_errors_ms(quality, truth):
    """Per run: error of the fitted clock at the first edge, and the worst over the run (ms)."""
    out = []
    for q in quality["runs"]:
        t = truth["runs"][q["run_id"]]
        offset = (t["daq"]["offset_s"] + t["daq"]["drift_ppm"] * 1e-6 * t["controller"]["first_edge_s"]) * 1e3
        d_drift = (q["clock_drift_ppm"] - t["daq"]["drift_ppm"]) * 1e-3
        err = q["clock_offset_ms"] - offset
        if q["source"] == "bin":  # a wrapping 32-bit microsecond counter fixes the clock modulo 2^32 us
            err = (err + 2 ** 31 * 1e-3) % (2 ** 32 * 1e-3) - 2 ** 31 * 1e-3
        out.append((err, max(abs(err + d_drift * s) for s in np.linspace(0, q["duration_s"], 40))))
    return out


@pytest.mark.parametrize("form", ["csv", "bin", "mcap", "mixed"])
def test_virtual_tunnel_in_every_form(tmp_path, form):
    root = vl_tunnel.generate_tunnel(tmp_path / f"vl-{form}", form=form, grid=GRID, flow_speeds=(0.0, 0.2),
                                     cycles=6, seed=2, bin_faults=True)
    truth = json.loads((root / "truth.json").read_text())
    result = ingest_campaign(root)
    assert result.quality["runs_ingested"] == 4
    for first_edge, worst in clock_errors_ms(result.quality, truth):
        # the bracketing samples pin the first edge to within half a 2 ms sample; over the run the
        # sampling phase of this rig (no controller jitter) barely moves, which limits the drift
        assert abs(first_edge) <= 1.0 + 0.01
        assert worst < 1.25
    if form in ("bin", "mixed"):
        faulty = [q for q in result.quality["runs"] if q["source"] == "bin"][0]
        assert faulty["dropped_frames"] > 0 and faulty["dropped_bytes"] > 0
    f = result.frame
    assert f["time_s"].min() < 0 and (f["time_s"] == 0).sum() == 4


def test_virtual_tunnel_interpolation_matches_a_held_out_measured_speed(tmp_path):
    root = vl_tunnel.generate_tunnel(tmp_path / "vl", grid=GRID, flow_speeds=(0.0, 0.1, 0.15, 0.2, 0.3), cycles=4,
                                     seed=1)
    frame = ingest_campaign(root).frame
    held = frame.filter(pl.col("flow_speed_mps") == 0.15)
    made = interpolate_flow_speeds(frame.filter(pl.col("flow_speed_mps") != 0.15), speeds=(0.15,))
    made = made.filter(pl.col("interpolated"))
    for (freq,), h in held.group_by(["frequency_hz"]):
        i = made.filter(pl.col("frequency_hz") == freq)
        t = i["time_s"].to_numpy()
        want = np.column_stack([np.interp(t, h["time_s"].to_numpy(), h[c].to_numpy()) for c in WRENCH_CHANNELS])
        got = i.select(list(WRENCH_CHANNELS)).to_numpy()
        inner = (t > 0.5) & (t < t.max() - 0.5)
        rms_err = np.sqrt(((want - got)[inner] ** 2).mean(axis=0))
        rms = np.sqrt((want[inner] ** 2).mean(axis=0))
        # within 10 % on the large channels; the small ones are at the load cell's noise and bias level
        assert np.all(rms_err < 0.1 * rms + 0.005), (freq, rms_err, rms)


def test_virtual_towing_tank(tmp_path):
    root = vl_towing.generate_towing(tmp_path / "tow", speeds=(0.1, 0.3), seed=0)
    result = ingest_campaign(root)
    f = result.frame
    assert set(f["heading"].unique()) == {"forward", "lateral"}
    steady = f.filter(pl.col("speed_mps") > 0.9 * pl.col("flow_speed_mps"))
    by_run = steady.group_by("run_id").agg(pl.col("flow_speed_mps").first(), pl.col("speed_mps").median())
    np.testing.assert_allclose(by_run["speed_mps"], by_run["flow_speed_mps"], rtol=0.01)
