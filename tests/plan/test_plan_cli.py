"""`workbench plan-campaign` on bad input: one line naming the file and the fault, exit 2, nothing written."""

from __future__ import annotations

import json

from workbench.cli import main


def _gaits(tmp_path):
    p = tmp_path / "straight-x.json"
    p.write_text(json.dumps({"solutions": [{"rank": 1, "params": {"theta_h_min_deg": -40.0, "theta_k_max_deg": -70.0,
                                                                  "frequency_hz": 0.6, "alpha_rad": [0, 1, 2, 3]}}]}))
    return p


def test_not_an_ensemble(tmp_path, capsys):
    out = tmp_path / "p.toml"
    assert main(["plan-campaign", "--model", str(tmp_path), "--gaits", str(_gaits(tmp_path)), "--n-runs", "2",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(tmp_path) in err[0] and "no ensemble.json" in err[0]
    assert not out.exists()


def test_bad_gait_file_and_unknown_setting(tmp_path, capsys):
    bad = tmp_path / "g.json"
    bad.write_text("{not json")
    assert main(["plan-campaign", "--model", str(tmp_path), "--gaits", str(bad), "--n-runs", "2",
                 "--out", str(tmp_path / "p.toml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(bad) in err[0] and "not a gait file" in err[0]
    assert main(["plan-campaign", "--model", str(tmp_path), "--gaits", str(_gaits(tmp_path)), "--n-runs", "2",
                 "--out", str(tmp_path / "p.toml"), "--set", "ranges.bogus=1"]) == 2
    err = capsys.readouterr().err
    # a ParamsError: the file, the key path and the allowed keys, in one line
    assert len(err.strip().splitlines()) == 1
    assert "plan.yaml" in err and "plan.ranges.bogus" in err and "unknown setting 'bogus'" in err
    assert "theta_h_min_deg" in err and "setup_s" in err
    assert not (tmp_path / "p.toml").exists()
    # a bad bound: the key path and the fault
    assert main(["plan-campaign", "--model", str(tmp_path), "--gaits", str(_gaits(tmp_path)), "--n-runs", "2",
                 "--out", str(tmp_path / "p.toml"), "--set", "ranges.frequency_hz=[0.6, 0.3]"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "plan.ranges" in err and "frequency_hz: lower bound 0.6" in err
