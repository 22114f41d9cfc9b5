"""campaign.toml parsing, part by part: each helper collects its own violations (inputs planted here)."""

from pathlib import Path

from workbench.contract.campaign import (
    _check_run_files,
    _Collector,
    _parse_cycles,
    _parse_id,
    _parse_motion,
    _parse_runs,
    _read_manifest,
    _towing_run_heading,
    _tunnel_run_params,
)
from workbench.errors import ContractError

TUNNEL_RUN = {"theta_h_min_deg": 10.0, "theta_h_max_deg": -100.0, "theta_k_min_deg": 80.0, "theta_k_max_deg": -20.0,
              "frequency_hz": 0.3, "phi_rad": 1.0}


def faults(col):
    return [(e.fault, e.run, e.where) for e in col.errors]


def test_tunnel_params_default_alpha_and_refuse_a_heading():
    col = _Collector(Path("c/campaign.toml"))
    params = _tunnel_run_params(dict(TUNNEL_RUN), "r1", col)
    assert params["alpha_rad"] == 0.0 and params["phi_rad"] == 1.0 and col.errors == []
    params = _tunnel_run_params({**TUNNEL_RUN, "frequency_hz": 0.0, "phi_rad": "x", "heading": "forward"}, "r2", col)
    assert "phi_rad" not in params
    assert faults(col) == [("'phi_rad' is missing or not a number", "r2", "field phi_rad"),
                           ("frequency_hz must be positive", "r2", "field frequency_hz"),
                           ("a water-tunnel run has no 'carriage' or 'heading'", "r2", None)]


def test_towing_heading_and_no_motion_file():
    col = _Collector(Path("c/campaign.toml"))
    assert _towing_run_heading({"heading": "lateral"}, "r1", col) == "lateral" and col.errors == []
    _towing_run_heading({"heading": "backwards", "motion": "m.csv"}, "r2", col)
    assert [f[0][:18] for f in faults(col)] == ["heading must be on", "a towing-tank run "]


def test_either_an_mcap_or_the_file_pair():
    col = _Collector(Path("c/campaign.toml"))
    _check_run_files({"mcap": "a.mcap"}, "r1", ("loadcell", "motion"), col)
    _check_run_files({"loadcell": "a.csv", "motion": "b.csv"}, "r2", ("loadcell", "motion"), col)
    assert col.errors == []
    _check_run_files({"mcap": "a.mcap", "motion": "b.csv"}, "r3", ("loadcell", "motion"), col)
    _check_run_files({"loadcell": "a.csv"}, "r4", ("loadcell", "carriage"), col)
    assert faults(col) == [("give either 'mcap' or the file pair ('loadcell', 'motion'), not both", "r3", None),
                           ("missing 'carriage' file (or 'mcap')", "r4", "field carriage")]


def test_cycles_positive_and_within_int32():
    col = _Collector(Path("c/campaign.toml"))
    assert _parse_cycles(None, "r", col) is None and _parse_cycles(7, "r", col) == 7
    assert _parse_cycles(2**31 - 1, "r", col) == 2**31 - 1 and col.errors == []
    for bad in (0, -3, True, 2.5, "5", 2**31):
        assert _parse_cycles(bad, "r", col) is None
    assert len(col.errors) == 6 and "too large" in col.errors[-1].fault and col.errors[-1].hint


def test_campaign_id_matches_pattern_and_folder(tmp_path):
    col = _Collector(tmp_path / "campaign.toml")
    root = tmp_path / "lab-1"
    assert _parse_id("lab-1", root, col) == "lab-1" and col.errors == []
    assert _parse_id("lab-2", root, col) == "lab-2"
    assert _parse_id(7, root, col) == "7"
    assert [e.fault[:25] for e in col.errors] == ["campaign id 'lab-2' diffe", "campaign id 7 must match "]


def test_motion_table_defaults():
    col = _Collector(Path("c/campaign.toml"))
    m = _parse_motion({"rate_hz": 65.0}, col)
    assert (m.rate_hz, m.feedback) == (65.0, False) and col.errors == []
    m = _parse_motion(None, col)
    assert m.rate_hz != m.rate_hz and [e.where for e in col.errors] == ["[motion] rate_hz"]


def test_duplicate_runs_keep_the_first(tmp_path):
    col = _Collector(tmp_path / "campaign.toml")
    run = {"flow_speed_mps": 0.1, "heading": "forward", "loadcell": "a.csv", "carriage": "b.csv"}
    runs = _parse_runs([{**run, "id": "r1"}, {**run, "id": "r1", "flow_speed_mps": 0.2}, "not a table",
                        {**run, "id": "r2"}], tmp_path, "towing_tank", col)
    assert [(r.id, r.flow_speed_mps) for r in runs] == [("r1", 0.1), ("r2", 0.1)]
    assert [(e.fault, e.run, e.where) for e in col.errors] == [("duplicate run id", "r1", None),
                                                               ("run entry is not a table", None, "[[runs]] #3")]


def test_read_manifest_one_error_naming_the_file(tmp_path):
    assert _read_manifest(tmp_path / "none", tmp_path / "none/campaign.toml").fault == "campaign folder does not exist"
    assert _read_manifest(tmp_path, tmp_path / "campaign.toml").fault == "missing campaign.toml"
    (tmp_path / "campaign.toml").write_bytes(b"\xef\xbb\xbfid = 'x'\n")
    assert _read_manifest(tmp_path, tmp_path / "campaign.toml") == {"id": "x"}     # a BOM is accepted
    (tmp_path / "campaign.toml").write_bytes("id = 'é'\n".encode("latin-1"))
    err = _read_manifest(tmp_path, tmp_path / "campaign.toml")
    assert isinstance(err, ContractError) and err.fault.startswith("not UTF-8") and "campaign.toml" in str(err.path)
    (tmp_path / "campaign.toml").write_text("id = \n")
    assert _read_manifest(tmp_path, tmp_path / "campaign.toml").fault.startswith("not valid TOML")
