"""`workbench fit-drag` and `workbench simulate` end to end: real ingest, files per the contract, bad input."""

import json

import numpy as np
import polars as pl
import pytest
from towing_fixture import PAPER, towing_frame, write_raw_towing_campaign

from workbench.cli import main


@pytest.fixture(scope="module")
def raw_towing(tmp_path_factory):
    root = tmp_path_factory.mktemp("raw") / "tow-fixture"
    return write_raw_towing_campaign(root, speeds=(0.10, 0.15, 0.20, 0.30, 0.35))


def test_fit_drag_on_a_raw_campaign_recovers_the_planted_drag(raw_towing, tmp_path, capsys):
    out = tmp_path / "drag"
    assert main(["fit-drag", str(raw_towing), "--out", str(out)]) == 0
    doc = json.loads((out / "drag.json").read_text())
    for heading in ("forward", "lateral"):
        entry = doc[heading]
        est, se, true = np.array(entry["coefficients"]), np.array(entry["stderr"]), np.array(PAPER[heading])
        assert np.all(np.abs(est - true) < 3 * se), (heading, est, se)
        assert entry["r2"] > 0.999 and entry["n_runs"] == 5
    assert (out / "drag.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    report = (out / "drag.md").read_text()
    assert "drag at rest" in report and "## lateral" in report
    assert "drag at rest" in capsys.readouterr().err


def test_fit_drag_recovers_the_papers_drag_from_a_virtual_lab_campaign(tmp_path):
    # the virtual towing tank tows with exactly the paper's polynomials, through the whole rig
    # (clocks, trigger line, load-cell bias, drift and noise, wake fluctuations; CSV, .bin and MCAP runs)
    from workbench.virtual_lab.towing import generate_towing

    raw = generate_towing(tmp_path / "vl-towing", scale="demo", seed=1, form="mixed")
    assert main(["fit-drag", str(raw), "--out", str(tmp_path / "drag")]) == 0
    doc = json.loads((tmp_path / "drag" / "drag.json").read_text())
    for heading in ("forward", "lateral"):
        est, se = np.array(doc[heading]["coefficients"]), np.array(doc[heading]["stderr"])
        assert np.all(np.abs(est - PAPER[heading]) < 3 * se), (heading, est, se)
        assert np.all(se < [0.5, 0.2, 0.02])
    assert any(f.startswith("drag at rest") for f in doc["forward"]["flags"])
    assert not doc["skipped_runs"]


def test_fit_drag_on_a_processed_file(tmp_path):
    path = tmp_path / "tow.parquet"
    towing_frame(repeats=1, seed=4).write_parquet(path)
    assert main(["fit-drag", str(path), "--out", str(tmp_path / "d")]) == 0
    doc = json.loads((tmp_path / "d" / "drag.json").read_text())
    assert set(doc) >= {"forward", "lateral"} and len(doc["lateral"]["stderr"]) == 3


def test_fit_drag_bad_input_is_one_line_and_leaves_the_previous_result(raw_towing, tmp_path, capsys):
    out = tmp_path / "drag"
    path = tmp_path / "tow.parquet"
    towing_frame(repeats=1).write_parquet(path)
    assert main(["fit-drag", str(path), "--out", str(out)]) == 0
    before = (out / "drag.json").read_bytes()
    capsys.readouterr()
    # too few speeds in this file: refused, naming it
    few = tmp_path / "few.parquet"
    towing_frame(speeds=(0.1, 0.2)).write_parquet(few)
    assert main(["fit-drag", str(few), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and str(few) in err and "at least 3 speeds" in err and "\n" not in err
    assert (out / "drag.json").read_bytes() == before
    # a water-tunnel campaign, and a folder that does not exist
    tunnel = tmp_path / "tun"
    tunnel.mkdir()
    (tunnel / "campaign.toml").write_text(
        'schema = "workbench/campaign@1"\nid = "tun"\nfacility = "water_tunnel"\n[loadcell]\nmodel = "x"\n'
        'rate_hz = 500.0\n[motion]\nrate_hz = 65.0\n[[runs]]\nid = "r1"\nflow_speed_mps = 0.1\n'
        'theta_h_min_deg = 10.0\ntheta_h_max_deg = -100.0\ntheta_k_min_deg = 80.0\ntheta_k_max_deg = -20.0\n'
        'frequency_hz = 0.3\nphi_rad = 1.0\nloadcell = "a.csv"\nmotion = "b.csv"\n')
    assert main(["fit-drag", str(tunnel), "--out", str(out)]) == 2
    assert "towing-tank" in capsys.readouterr().err
    assert main(["fit-drag", str(tmp_path / "nowhere"), "--out", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert (out / "drag.json").read_bytes() == before


def _gaits_file(path):
    doc = {"task": "straight", "model": "ef", "solutions": [
        {"rank": 1, "params": {"theta_h_min_deg": -20.0, "theta_k_max_deg": -50.0, "frequency_hz": 0.5,
                               "alpha_rad": [0.0, 0.0, 3.14, 3.14]}, "objectives": {"f1": -1, "f2": 0, "f3": 9},
         "score": 1.0},
        {"rank": 2, "params": {"theta_h_min_deg": 10.0, "theta_k_max_deg": -20.0, "frequency_hz": 0.6,
                               "alpha_rad": [0.0, 3.14, 0.0, 3.14]}, "score": 2.0}]}
    path.write_text(json.dumps(doc))
    return path


def test_simulate_a_gaits_file_and_a_command_line_gait(tmp_path, raw_towing):
    gaits = _gaits_file(tmp_path / "straight-ef.json")
    out = tmp_path / "sim"
    assert main(["simulate", "--gaits", str(gaits), "--rank", "2", "--gait", "theta_h_min_deg=-30",
                 "theta_k_max_deg=-60", "frequency_hz=0.4", "alpha_rad=0", "--duration", "4", "--out", str(out)]) == 0
    frame = pl.read_parquet(out / "trajectory.parquet")
    assert frame["label"].unique(maintain_order=True).to_list() == ["straight-ef #2", "gait 1"]
    assert frame.height == 2 * (int(round(4 * 65)) + 1)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["gaits"][1]["final_y_m"] > 0 and abs(summary["gaits"][1]["final_x_m"]) < 1e-12
    assert summary["gaits"][0]["params"]["alpha_rad"] == [0.0, 3.14, 0.0, 3.14]
    assert (out / "paths.png").stat().st_size > 1000
    # with a fitted drag.json
    assert main(["fit-drag", str(raw_towing), "--out", str(tmp_path / "drag")]) == 0
    assert main(["simulate", "--gaits", str(gaits), "--drag", str(tmp_path / "drag" / "drag.json"),
                 "--duration", "2", "--out", str(tmp_path / "sim2")]) == 0
    summary = json.loads((tmp_path / "sim2" / "summary.json").read_text())
    assert summary["robot"]["drag_source"].endswith("drag.json") and len(summary["gaits"]) == 2


@pytest.mark.parametrize("argv,message", [
    (["--gait", "theta_h_min_deg=-30", "frequency_hz=0.4"], "lacks"),
    (["--gait", "speed=3"], "KEY=VALUE"),
    (["--gait", "theta_h_min_deg=-30", "theta_k_max_deg=-60", "frequency_hz=0.4", "alpha_rad=0,1"], "four"),
    (["--gaits", "missing.json"], "not found"),
    (["--gait", "theta_h_min_deg=-30", "theta_k_max_deg=-60", "frequency_hz=0.4", "alpha_rad=0",
      "--model", "nonsense"], "unknown leg force model"),
    ([], "no gait given"),
])
def test_simulate_refuses_bad_input(argv, message, tmp_path, capsys):
    assert main(["simulate", *argv, "--duration", "1", "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and message in err
    assert not (tmp_path / "s").exists()


def test_simulate_reports_a_gait_that_did_not_converge(tmp_path, capsys):
    import yaml

    robot = yaml.safe_load(open("pipelines/robot.yaml"))
    robot["simulation"].update(max_iter=1, tol_mps=1e-9)      # one iteration per window cannot reach 1e-9
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(robot))
    out = tmp_path / "sim"
    assert main(["simulate", "--gait", "theta_h_min_deg=-30", "theta_k_max_deg=-60", "frequency_hz=0.4",
                 "alpha_rad=0,1,2,3", "--robot", str(tmp_path / "robot.yaml"), "--duration", "3",
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "gait 1: the simulation did NOT converge" in err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["converged_all"] is False and summary["unconverged"] == ["gait 1"]
    assert summary["gaits"][0]["converged"] is False and summary["gaits"][0]["fixed_point_residual_mps"] > 1e-9
    # the same gait with the file's own settings converges and says nothing
    assert main(["simulate", "--gait", "theta_h_min_deg=-30", "theta_k_max_deg=-60", "frequency_hz=0.4",
                 "alpha_rad=0,1,2,3", "--duration", "3", "--out", str(tmp_path / "ok")]) == 0
    assert "NOT converge" not in capsys.readouterr().err
    assert json.loads((tmp_path / "ok" / "summary.json").read_text())["converged_all"] is True
