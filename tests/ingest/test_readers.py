"""Every reader behind the one protocol: the same planted run read from CSV, .bin and MCAP agrees."""

from __future__ import annotations

import numpy as np
import pytest
from ingest_fixtures import CALIBRATION, RunPlan

from workbench.contract.campaign import load_campaign
from workbench.contract.columns import WRENCH_CHANNELS
from workbench.contract.serial import FRAME_SIZE
from workbench.errors import ContractError
from workbench.ingest.readers import BinReader, CsvReader, McapReader, ReadSpec, make_reader, read_run


@pytest.fixture
def forms(campaign):
    """The same two runs written in each form."""
    return {form: campaign([RunPlan("r1", form=form), RunPlan("r2", form=form, flow_speed=0.2)], name=f"c-{form}")
            for form in ("csv", "bin", "mcap")}


def test_make_reader_picks_the_implementation_by_file(forms):
    spec = ReadSpec(run="r1", facility="water_tunnel", calibration=CALIBRATION)
    assert isinstance(make_reader(forms["csv"] / "runs/r1.loadcell.csv", "loadcell", spec), CsvReader)
    assert isinstance(make_reader(forms["bin"] / "runs/r1.loadcell.bin", "loadcell", spec), BinReader)
    assert isinstance(make_reader(forms["mcap"] / "runs/r1.mcap", "mcap", spec), McapReader)
    with pytest.raises(ContractError, match="can only be a load-cell log"):
        make_reader(forms["bin"] / "runs/r1.loadcell.bin", "motion", spec)
    with pytest.raises(ContractError, match="'loadcell' file must be .csv or .bin"):
        make_reader(forms["csv"] / "runs/r1.loadcell.parquet", "loadcell", spec)


def test_all_readers_give_the_same_streams(forms):
    streams = {}
    for form, root in forms.items():
        camp = load_campaign(root)
        streams[form] = read_run(camp, camp.runs[0])
        assert set(streams[form]) == {"loadcell", "motion"}
        assert all(s.source == form for s in streams[form].values() if s.role == "loadcell")
    ref = streams["csv"]
    for form in ("bin", "mcap"):
        lc, lc0 = streams[form]["loadcell"], ref["loadcell"]
        assert len(lc) == len(lc0)
        # .bin keeps microseconds on a wrapped 32-bit counter; MCAP and CSV carry the float
        np.testing.assert_allclose(np.diff(lc.time_s), np.diff(lc0.time_s), atol=1.5e-6)
        np.testing.assert_array_equal(lc.sync, lc0.sync)
        for c in WRENCH_CHANNELS:
            # .bin: counts quantise to 1e-4 N / 1e-5 N m (plus crosstalk terms)
            np.testing.assert_allclose(lc.values[c], lc0.values[c], atol=2e-4)
        m, m0 = streams[form]["motion"], ref["motion"]
        np.testing.assert_allclose(m.time_s, m0.time_s, rtol=0, atol=1e-9)
        np.testing.assert_allclose(m.values["hfe_cmd_deg"], m0.values["hfe_cmd_deg"], atol=1e-9)


def test_bin_reader_resynchronises_and_counts_dropped_bytes_and_frames(forms):
    root = forms["bin"]
    path = root / "runs/r1.loadcell.bin"
    good = path.read_bytes()
    n_frames = len(good) // FRAME_SIZE
    damaged = bytearray(good[13:])                      # capture starts mid-frame
    first = FRAME_SIZE - 13                             # where the first whole frame now starts

    def frame(k):
        return first + FRAME_SIZE * k
    damaged[frame(800):frame(800)] = b"\x00\xaa\x55\x13"  # line noise between two frames
    damaged[frame(500) + 7] ^= 0x5A                     # one corrupt byte: that frame's checksum fails
    del damaged[frame(100): frame(103)]                 # three frames lost on the wire
    path.write_bytes(bytes(damaged))
    camp = load_campaign(root)
    lc = read_run(camp, camp.runs[0])["loadcell"]
    assert len(lc) == n_frames - 1 - 3 - 1
    assert lc.dropped_frames == 3 + 1  # the partial first frame is no gap in the counter
    assert lc.dropped_bytes == len(damaged) - FRAME_SIZE * len(lc)
    assert np.all(np.diff(lc.time_s) > 0)


def test_bin_reader_unwraps_the_device_counter(campaign):
    # device clock planted so the 32-bit microsecond counter wraps (at 4294.967296 s) mid-run
    root = campaign([RunPlan("r1", form="bin", offset_s=4294.967296 - 1000.0 - 4.0, drift_ppm=30.0)])
    camp = load_campaign(root)
    lc = read_run(camp, camp.runs[0])["loadcell"]
    raw = np.frombuffer((root / "runs/r1.loadcell.bin").read_bytes(), dtype=np.uint8).reshape(-1, 32)
    t32 = raw[:, 2:6].copy().view("<u4").ravel()
    assert np.any(np.diff(t32.astype(np.int64)) < 0), "fixture should wrap"
    assert np.all(np.diff(lc.time_s) > 0)
    np.testing.assert_allclose(np.diff(lc.time_s), 0.002, atol=2e-6)


def test_bin_reader_applies_the_calibration_matrix(campaign):
    root = campaign([RunPlan("r1", form="bin")])
    camp = load_campaign(root)
    lc = read_run(camp, camp.runs[0])["loadcell"]
    raw = np.frombuffer((root / "runs/r1.loadcell.bin").read_bytes(), dtype=np.uint8).reshape(-1, 32)
    counts = raw[:, 6:30].copy().view("<i4").reshape(-1, 6).astype(float)
    expected = counts @ CALIBRATION.T
    np.testing.assert_allclose(np.column_stack([lc.values[c] for c in WRENCH_CHANNELS]), expected, rtol=1e-12)


def test_feedback_logs_read_measured_angles(campaign):
    root = campaign([RunPlan("r1")], feedback=True)
    camp = load_campaign(root)
    m = read_run(camp, camp.runs[0])["motion"]
    np.testing.assert_allclose(m.values["hfe_meas_deg"], m.values["hfe_cmd_deg"] - 1.0)


def test_towing_runs_read_the_carriage_log(campaign):
    for form in ("csv", "mcap"):
        root = campaign([RunPlan("t1", form=form, flow_speed=0.2)], facility="towing_tank", name=f"tow-{form}")
        camp = load_campaign(root)
        streams = read_run(camp, camp.runs[0])
        assert set(streams) == {"loadcell", "carriage"}
        assert streams["carriage"].values["position_m"].max() == pytest.approx(0.2 * 8.0, rel=1e-3)


def test_readers_ignore_unknown_files(campaign):
    root = campaign()
    (root / "truth.json").write_text("{}")
    (root / "runs" / "notes.txt").write_text("pump noisy today")
    camp = load_campaign(root)
    assert len(read_run(camp, camp.runs[0])["loadcell"]) > 0
