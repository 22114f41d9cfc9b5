"""Tunnel campaigns follow the contract in every form, carry their ground truth, and are deterministic."""

import json
import math
import tomllib

import numpy as np
import polars as pl
import pytest
from vl_helpers import SMALL_GRID, small_tunnel

from workbench.contract.campaign import check_manifest, load_campaign
from workbench.contract.columns import LOADCELL_COLUMNS, MOTION_COLUMNS, MOTION_FEEDBACK_COLUMNS
from workbench.contract.serial import FRAME_DTYPE, FRAME_SIZE
from workbench.errors import ContractError, WorkbenchError
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.motion import JointSinusoid, LegMotion
from workbench.virtual_lab import writers
from workbench.virtual_lab.settings import LoadCellSettings, demo_grid, paper_grid
from workbench.virtual_lab.tunnel import prescribed


def truth_of(root):
    return json.loads((root / "truth.json").read_text())


def header(path):
    return tuple(path.read_text().split("\n", 1)[0].split(","))


def rising(sync):
    s = np.asarray(sync).astype(int)
    return np.flatnonzero(np.diff(np.r_[0, s]) == 1)


# ----------------------------------------------------------------------- grids, manifest
def test_paper_and_demo_grids():
    paper = paper_grid()
    assert len(paper) == 480 and len({tuple(p.values()) for p in paper}) == 480
    assert {p["theta_h_min_deg"] for p in paper} == {10.0, -10.0, -30.0, -50.0}
    assert {p["theta_k_max_deg"] for p in paper} == {-20.0, -40.0, -60.0, -80.0}
    assert all(p["theta_h_max_deg"] == -100.0 and p["theta_k_min_deg"] == 80.0 for p in paper)
    assert min(p["frequency_hz"] for p in paper) == 0.3 and max(p["frequency_hz"] for p in paper) == 0.6
    ticks = sum(10 / p["frequency_hz"] * 65 for p in paper) * 4
    assert 2.7e6 < ticks < 3.2e6  # "about 3 million data points"
    demo = demo_grid()
    assert len(demo) == 48
    pairs = {(p["theta_h_min_deg"], p["theta_k_max_deg"]) for p in demo}
    assert (10.0, -20.0) in pairs and (-50.0, -60.0) in pairs  # the paper's two figure cases
    ticks = sum(5 / p["frequency_hz"] * 65 for p in demo) * 4
    assert 140_000 < ticks < 250_000


def test_manifest_follows_the_contract(tunnel_csv):
    camp, errors = check_manifest(tunnel_csv)
    assert errors == []
    assert camp.id == tunnel_csv.name and camp.facility == "water_tunnel"
    assert camp.motion.rate_hz == 65.0 and camp.motion.feedback is False
    assert camp.loadcell.rate_hz == 500.0 and camp.loadcell.calibration is None
    assert len(camp.runs) == 6
    r = camp.runs[0]
    assert r.cycles == 2 and r.flow_speed_mps == 0.0
    assert dict(r.params) == {**SMALL_GRID[0], "theta_h_max_deg": -100.0, "theta_k_min_deg": 80.0, "alpha_rad": 0.0}
    assert r.loadcell.name == "r0001.loadcell.csv" and r.motion.name == "r0001.motion.csv"
    assert [x.flow_speed_mps for x in camp.runs] == [0.0] * 3 + [0.2] * 3


def test_csv_headers_are_exact(tunnel_csv, tunnel_mixed):
    assert header(tunnel_csv / "runs" / "r0001.loadcell.csv") == LOADCELL_COLUMNS
    assert header(tunnel_csv / "runs" / "r0001.motion.csv") == MOTION_COLUMNS
    assert header(tunnel_mixed / "runs" / "r0001.motion.csv") == MOTION_COLUMNS + MOTION_FEEDBACK_COLUMNS


def test_mixed_campaign_uses_all_three_forms(tunnel_mixed):
    camp = load_campaign(tunnel_mixed)
    assert check_manifest(tunnel_mixed)[1] == []
    assert camp.motion.feedback is True
    kinds = [("mcap" if r.mcap else r.loadcell.suffix) for r in camp.runs]
    assert kinds == [".csv", ".bin", "mcap"] * 2
    cal = camp.loadcell.calibration_matrix()
    np.testing.assert_allclose(cal, writers_calibration(), rtol=0, atol=0)


def writers_calibration():
    from workbench.virtual_lab.rig import calibration_matrix

    return calibration_matrix(LoadCellSettings())


# ------------------------------------------------------------------------- determinism
def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path):
    kw = dict(grid=SMALL_GRID[:1], flow_speeds=(0.1,), cycles=1, form="mixed")
    a = small_tunnel(tmp_path / "a" / "camp", seed=3, **kw)
    b = small_tunnel(tmp_path / "b" / "camp", seed=3, **kw)
    c = small_tunnel(tmp_path / "c" / "camp", seed=4, **kw)
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert {p.relative_to(b) for p in b.rglob("*") if p.is_file()} == set(files)
    for f in files:
        assert (a / f).read_bytes() == (b / f).read_bytes(), f
    assert (a / "runs/r0001.loadcell.csv").read_bytes() != (c / "runs/r0001.loadcell.csv").read_bytes()


# ------------------------------------------------------------------- trigger and clocks
def test_trigger_line_and_rest_stretches(tunnel_csv):
    truth = truth_of(tunnel_csv)
    for rid, r in truth["runs"].items():
        m = pl.read_csv(tunnel_csv / "runs" / f"{rid}.motion.csv")
        t, sync = m["time_s"].to_numpy(), m["sync"].to_numpy()
        edges = rising(sync)
        start = r["controller"]["start_tick"]
        assert edges[0] == start == 65 and sync[:start].sum() == 0  # a 1 s rest, line low
        assert list(np.diff(edges)) == [65] * (len(edges) - 1)  # every 1.000 s of the controller clock
        motion_s = 2 / r["params"]["frequency_hz"] + r["controller"]["ease_s"]
        assert r["controller"]["ease_s"] == pytest.approx(0.4)
        assert len(edges) == r["controller"]["edges"] == math.floor(motion_s) + 1
        assert sync.sum() == 7 * len(edges)  # high 0.1 s: 7 ticks at 65 Hz
        assert t[start] == pytest.approx(r["controller"]["first_edge_s"], abs=1e-6)
        np.testing.assert_allclose(np.diff(t), 1 / 65, atol=2e-6)
        hfe = m["hfe_cmd_deg"].to_numpy()
        assert np.ptp(hfe[: start + 1]) == 0  # at rest at the start pose until the run starts
        end = start + math.ceil(motion_s * 65)
        assert np.ptp(hfe[end:]) < 1e-3 and abs(hfe[end] - hfe[start]) < 1e-3  # whole cycles: back at rest


def test_loadcell_clock_and_sync_match_the_recorded_truth(tunnel_csv):
    truth = truth_of(tunnel_csv)
    for rid, r in truth["runs"].items():
        lc = pl.read_csv(tunnel_csv / "runs" / f"{rid}.loadcell.csv")
        m = pl.read_csv(tunnel_csv / "runs" / f"{rid}.motion.csv")
        d = r["daq"]
        assert 20 <= abs(d["drift_ppm"]) <= 200
        t_daq = lc["time_s"].to_numpy()
        assert np.diff(t_daq) == pytest.approx(1 / 500, abs=1.5e-6)
        t_ctrl = (t_daq - d["offset_s"]) / (1 + d["drift_ppm"] * 1e-6)
        ctrl_edges = m["time_s"].to_numpy()[rising(m["sync"])]
        lc_edges = rising(lc["sync"])
        assert len(lc_edges) == len(ctrl_edges)
        # each edge is seen on the first DAQ sample at or after it (controller clock)
        after = t_ctrl[lc_edges] - ctrl_edges
        before = t_ctrl[lc_edges - 1] - ctrl_edges
        assert (after >= -1e-6).all() and (after < 2e-3 + 1e-6).all() and (before < 1e-6).all()
        # the capture covers the whole controller log with margins
        assert t_ctrl[0] < m["time_s"][0] and t_ctrl[-1] > m["time_s"][-1]
        # the edge fit recovers offset and drift (midpoint of the sampling interval)
        mid = 0.5 * (t_daq[lc_edges] + t_daq[lc_edges - 1])
        slope, icpt = np.polyfit(ctrl_edges, mid, 1)
        assert icpt + slope * ctrl_edges[0] == pytest.approx(d["first_edge_daq_s"], abs=1e-3)


# ------------------------------------------------------------------------------- forms
def decode_bin(raw: bytes):
    """Resynchronising decoder: valid frames and the number of bytes skipped."""
    b = np.frombuffer(raw, np.uint8)
    starts, skipped, i = [], 0, 0
    while i + FRAME_SIZE <= len(b):
        if b[i] == 0xAA and b[i + 1] == 0x55 and int(b[i:i + 31].sum()) % 256 == b[i + 31]:
            starts.append(i)
            i += FRAME_SIZE
        else:
            i += 1
            skipped += 1
    frames = np.frombuffer(b"".join(raw[s:s + FRAME_SIZE] for s in starts), FRAME_DTYPE)
    return frames, skipped


def test_bin_frames_decode_to_the_same_readings_as_csv(tunnel_csv, tunnel_mixed):
    raw = (tunnel_mixed / "runs" / "r0005.loadcell.bin").read_bytes()
    assert len(raw) % FRAME_SIZE == 0
    frames = np.frombuffer(raw, FRAME_DTYPE)
    assert (frames["header"] == [0xAA, 0x55]).all()
    sums = np.frombuffer(raw, np.uint8).reshape(-1, 32)[:, :31].astype(int).sum(axis=1) % 256
    assert (sums == frames["checksum"]).all()
    cal = load_campaign(tunnel_mixed).loadcell.calibration_matrix()
    si = frames["counts"].astype(float) @ cal.T
    csv = pl.read_csv(tunnel_csv / "runs" / "r0005.loadcell.csv")
    np.testing.assert_allclose(si, csv.select(LOADCELL_COLUMNS[1:7]).to_numpy(), atol=3e-5)
    np.testing.assert_array_equal(frames["sync"], csv["sync"].to_numpy())
    t_us = np.round(csv["time_s"].to_numpy() * 1e6).astype(np.int64) % 2**32
    np.testing.assert_array_equal(frames["time_us"], t_us)


def test_bin_faults_for_ingest(tunnel_mixed):
    rec = truth_of(tunnel_mixed)["runs"]["r0002"]["bin"]
    raw = (tunnel_mixed / "runs" / "r0002.loadcell.bin").read_bytes()
    frames, skipped = decode_bin(raw)
    lost = len(rec["corrupted_frames"]) + len(rec["dropped"])
    assert rec["mid_frame_prefix_bytes"] > 0 and len(rec["corrupted_frames"]) == 3 and len(rec["dropped"]) == 2
    assert rec["frames"] - lost <= len(frames) <= rec["frames"] - lost + 2  # a damaged frame may resync partly
    assert skipped > rec["mid_frame_prefix_bytes"]
    assert rec["counter_wraps"]
    dt = np.diff(frames["time_us"].astype(np.int64))
    assert (dt < -2**31).sum() == 1  # the device counter wraps once, mid-run


def test_mcap_runs_carry_the_csv_columns(tunnel_csv, tunnel_mixed):
    from mcap.reader import make_reader

    with open(tunnel_mixed / "runs" / "r0006.mcap", "rb") as fh:
        msgs = [(s.name, c.topic, c.message_encoding, m.log_time, json.loads(m.data))
                for s, c, m in make_reader(fh).iter_messages(log_time_order=False)]
    topics = {t for _, t, _, _, _ in msgs}
    assert topics == {"/loadcell/wrench", "/leg/joint_command"}
    assert {(s, t) for s, t, _, _, _ in msgs} == {("workbench.Wrench", "/loadcell/wrench"),
                                                  ("workbench.JointCommand", "/leg/joint_command")}
    assert all(e == "json" for _, _, e, _, _ in msgs)
    log_times = [lt for *_, lt, _ in msgs]
    assert log_times == sorted(log_times)
    wrench = [d for _, t, _, _, d in msgs if t == "/loadcell/wrench"]
    joint = [d for _, t, _, _, d in msgs if t == "/leg/joint_command"]
    assert tuple(wrench[0]) == LOADCELL_COLUMNS
    assert tuple(joint[0]) == MOTION_COLUMNS + MOTION_FEEDBACK_COLUMNS
    csv = pl.read_csv(tunnel_csv / "runs" / "r0006.loadcell.csv")
    assert len(wrench) == csv.height
    np.testing.assert_allclose([w["fy_n"] for w in wrench], csv["fy_n"].to_numpy(), atol=2e-6)
    np.testing.assert_array_equal([w["time_s"] for w in wrench], csv["time_s"].to_numpy())
    motion = pl.read_csv(tunnel_csv / "runs" / "r0006.motion.csv")
    np.testing.assert_array_equal([j["hfe_cmd_deg"] for j in joint], motion["hfe_cmd_deg"].to_numpy())


# -------------------------------------------------------------------------- ground truth
def test_ef_truth_reading_is_ef_plus_bias_drift_and_noise(tmp_path):
    out = small_tunnel(tmp_path / "ef", seed=9, truth="ef", grid=SMALL_GRID[1:2], flow_speeds=(0.2,))
    r = truth_of(out)["runs"]["r0001"]
    lc = pl.read_csv(out / "runs" / "r0001.loadcell.csv")
    t_daq = lc["time_s"].to_numpy()
    d = r["daq"]
    t_ctrl = (t_daq - d["offset_s"]) / (1 + d["drift_ppm"] * 1e-6)
    js = JointSinusoid.from_params(r["params"])
    cycles_s = r["cycles"] / r["params"]["frequency_hz"]
    th, om, al = prescribed(js, t_ctrl, r["controller"]["first_edge_s"], cycles_s, r["controller"]["ease_s"])
    motion = LegMotion.from_arrays(0.002, th[:, 0], th[:, 1], om[:, 0], om[:, 1], 0.2, al[:, 0], al[:, 1])
    ef = EmpiricalFormula().wrench(motion)[0]
    bias, drift = np.array(r["loadcell"]["bias"]), np.array(r["loadcell"]["drift_per_s"])
    resid = lc.select(LOADCELL_COLUMNS[1:7]).to_numpy() - ef - bias - drift * (t_daq - t_daq[0])[:, None]
    lcs = LoadCellSettings()
    np.testing.assert_allclose(resid.std(axis=0)[:3], lcs.noise_n, rtol=0.1)
    np.testing.assert_allclose(resid.std(axis=0)[3:], lcs.noise_nm, rtol=0.1)
    assert np.abs(resid.mean(axis=0)[:3]).max() < 5 * lcs.noise_n / np.sqrt(len(resid))
    assert np.abs(ef[:, 1]).max() > 5 * lcs.noise_n  # and the EF force is well above the noise


def test_noise_bias_and_forces_in_range(tunnel_csv):
    truth = truth_of(tunnel_csv)
    for rid, r in truth["runs"].items():
        lc = pl.read_csv(tunnel_csv / "runs" / f"{rid}.loadcell.csv")
        rest = lc["fy_n"].to_numpy()[:100]  # before the controller log: the leg hangs at rest
        if r["flow_speed_mps"] == 0:
            assert 0.005 < rest.std() < 0.02
        assert max(abs(b) for b in r["loadcell"]["bias"][:3]) < 0.02
        # field notes: 0.02-0.5 N; the rotating-plate added mass (m_a omega v_t) takes the fastest
        # strokes at 0.3 m/s to about 0.75 N RMS (4 of the demo's 192 runs above 0.5 N)
        assert 0.02 < r["wrench_rms"][1] < 1.0 and 0.02 < r["wrench_rms"][2] < 1.0


# ------------------------------------------------------------------- the folder as a whole
def test_refuses_foreign_folders_and_bad_ids(tmp_path):
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("precious")
    with pytest.raises(WorkbenchError, match="refusing"):
        small_tunnel(foreign)
    assert (foreign / "notes.txt").read_text() == "precious"
    with pytest.raises(ContractError):
        small_tunnel(tmp_path / "Bad Name")
    with pytest.raises(ContractError):
        small_tunnel(tmp_path / "camp", campaign_id="other")
    with pytest.raises(WorkbenchError):
        small_tunnel(tmp_path / "camp", effects=["servo_lag:tau_s=-1"])
    with pytest.raises(WorkbenchError):
        small_tunnel(tmp_path / "camp", form="parquet")
    assert not (tmp_path / "camp").exists()


def test_regenerates_its_own_folder_and_keeps_it_on_failure(tmp_path, monkeypatch):
    kw = dict(grid=SMALL_GRID[:1], flow_speeds=(0.1,), cycles=1)
    out = small_tunnel(tmp_path / "camp", seed=1, **kw)
    before = (out / "campaign.toml").read_bytes()
    small_tunnel(tmp_path / "camp", seed=2, **kw)  # its own folder: replaced
    assert truth_of(out)["seed"] == 2
    calls = []

    def broken(path, cols):
        calls.append(path)
        raise OSError("disk full")

    monkeypatch.setattr(writers, "write_csv", broken)
    with pytest.raises(OSError):
        small_tunnel(tmp_path / "camp", seed=3, **kw)
    assert calls and truth_of(out)["seed"] == 2  # the previous campaign is intact
    assert (out / "campaign.toml").read_bytes() == before  # (same grid: same manifest)
    assert [p.name for p in tmp_path.iterdir()] == ["camp"]  # no temporary folder left behind
    tomllib.loads((out / "campaign.toml").read_text())


def test_eased_motion_has_no_velocity_step_and_full_cycles():
    js = JointSinusoid.from_params({**SMALL_GRID[0], "theta_h_max_deg": -100.0, "theta_k_min_deg": 80.0})
    t = np.arange(-1, 6, 0.001)
    cycles_s = 2 / 0.6
    th, om, al = prescribed(js, t, 0.0, cycles_s, 0.4)
    assert np.abs(np.diff(om, axis=0)).max() < 2.0  # deg/s per ms: no step
    np.testing.assert_allclose(om, np.gradient(th, 0.001, axis=0), atol=0.2)
    np.testing.assert_allclose(al[1:-1], np.gradient(om, 0.001, axis=0)[1:-1], atol=5.0)
    np.testing.assert_allclose(th[t >= cycles_s + 0.4], th[0:1].repeat((t >= cycles_s + 0.4).sum(), 0), atol=1e-9)
    # between the ramps: the paper's eq. 3, half a ramp late
    mid = (t > 1.0) & (t < 2.5)
    th_eq, tk_eq, *_ = js.evaluate(t[mid] - 0.2)
    np.testing.assert_allclose(th[mid, 0], th_eq, atol=1e-9)
    bare, _, _ = prescribed(js, t, 0.0, cycles_s, 0.0)
    np.testing.assert_allclose(bare[(t > 0) & (t < cycles_s), 1], js.evaluate(t[(t > 0) & (t < cycles_s)])[1])
