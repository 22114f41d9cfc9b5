"""Towing-tank campaigns: the paper's drag polynomials in the steady phases, inertia in the ramps."""

import json

import numpy as np
import polars as pl
import pytest

from workbench.contract.campaign import check_manifest
from workbench.contract.columns import CARRIAGE_COLUMNS, LOADCELL_COLUMNS
from workbench.virtual_lab.towing import drag_n, generate_towing

FWD = (9.997, -0.132, 0.334)
LAT = (15.571, 0.937, 0.055)


def steady_and_ramp(root, rid, r):
    lc = pl.read_csv(root / "runs" / f"{rid}.loadcell.csv")
    d = r["daq"]
    t = (lc["time_s"].to_numpy() - d["offset_s"]) / (1 + d["drift_ppm"] * 1e-6)
    ph = r["phases"]
    steady = (t > ph["steady_start_s"] + 0.5) & (t < ph["steady_end_s"] - 0.5)
    ramp = (t > ph["accel_start_s"] + 0.1) & (t < ph["steady_start_s"] - 0.1)
    return lc, steady, ramp


def test_manifest_and_headers(towing_csv):
    camp, errors = check_manifest(towing_csv)
    assert errors == [] and camp.facility == "towing_tank" and camp.motion is None
    assert [r.heading for r in camp.runs] == ["forward"] * 6 + ["lateral"] * 6
    assert [r.flow_speed_mps for r in camp.runs[:6]] == [0.1, 0.15, 0.2, 0.25, 0.3, 0.35]
    r = camp.runs[0]
    assert r.carriage.name == "r0001.carriage.csv" and r.motion is None
    for f in ("r0001.loadcell.csv", "r0001.carriage.csv"):
        head = tuple((towing_csv / "runs" / f).read_text().split("\n", 1)[0].split(","))
        assert head == (LOADCELL_COLUMNS if "loadcell" in f else CARRIAGE_COLUMNS)


def test_steady_forces_follow_the_paper_polynomials(towing_csv):
    truth = json.loads((towing_csv / "truth.json").read_text())
    for rid, r in truth["runs"].items():
        lc, steady, _ = steady_and_ramp(towing_csv, rid, r)
        forward = r["heading"] == "forward"
        c2, c1, c0 = FWD if forward else LAT
        v = r["speed_mps"]
        expected = c2 * v * v + c1 * v + c0
        on, off = ("fy_n", "fx_n") if forward else ("fx_n", "fy_n")
        mean = lc[on].to_numpy()[steady].mean()
        assert mean == pytest.approx(-expected, rel=0.02, abs=0.01), (rid, mean, expected)  # drag reads negative
        assert abs(lc[off].to_numpy()[steady].mean()) < 0.05 * expected + 0.01
        # the drag acts below the load cell: a torque about the other horizontal axis
        torque = lc["tx_nm" if forward else "ty_nm"].to_numpy()[steady].mean()
        assert torque == pytest.approx((0.08 if forward else -0.08) * mean, rel=0.1, abs=0.003)


def test_acceleration_phase_adds_the_inertia(towing_csv):
    truth = json.loads((towing_csv / "truth.json").read_text())
    for rid, r in truth["runs"].items():
        if r["speed_mps"] < 0.3:
            continue
        lc, _, ramp = steady_and_ramp(towing_csv, rid, r)
        d = r["daq"]
        t = (lc["time_s"].to_numpy() - d["offset_s"]) / (1 + d["drift_ppm"] * 1e-6)
        v = 0.25 * (t[ramp] - r["phases"]["accel_start_s"])
        coeffs = FWD if r["heading"] == "forward" else LAT
        drag = drag_n(coeffs, v, 0.05)
        inertia = -(lc[r["channel"]].to_numpy()[ramp] + drag)
        assert inertia.mean() == pytest.approx(r["effective_mass_kg"] * 0.25, rel=0.1)


def test_carriage_log_and_trigger(towing_csv):
    truth = json.loads((towing_csv / "truth.json").read_text())
    r = truth["runs"]["r0006"]
    c = pl.read_csv(towing_csv / "runs" / "r0006.carriage.csv")
    pos, sync = c["position_m"].to_numpy(), c["sync"].to_numpy()
    assert (np.diff(pos) >= 0).all() and 2.5 < pos[-1] <= 3.0
    edges = np.flatnonzero(np.diff(np.r_[0, sync]) == 1)
    assert edges[0] == r["controller"]["start_tick"] == 100
    assert set(np.diff(edges)) == {100} and sync.sum() == 10 * len(edges)
    speed = np.diff(pos) * 100
    assert np.median(speed[speed > 0.3]) == pytest.approx(0.35, abs=0.002)


def test_every_form_and_determinism(tmp_path):
    kw = dict(speeds=(0.2, 0.3), seed=5, form="mixed")
    a = generate_towing(tmp_path / "a" / "tow", **kw)
    b = generate_towing(tmp_path / "b" / "tow", **kw)
    assert check_manifest(a)[1] == []
    for f in sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file()):
        assert (a / f).read_bytes() == (b / f).read_bytes()
    from mcap.reader import make_reader

    with open(a / "runs" / "r0003.mcap", "rb") as fh:
        topics = {c.topic for _, c, _ in make_reader(fh).iter_messages()}
    assert topics == {"/loadcell/wrench", "/carriage/position"}
    assert (a / "runs" / "r0002.loadcell.bin").stat().st_size % 32 == 0
