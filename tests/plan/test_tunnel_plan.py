"""`virtual-lab tunnel --plan`: exactly the planned runs; a plan's manifest reads as 'files pending'."""

from __future__ import annotations

import json
import tomllib

import pytest

from workbench.cli import main
from workbench.errors import ContractError
from workbench.virtual_lab.tunnel import generate_tunnel

PLAN = """\
schema = "workbench/campaign@1"
id = "next"
facility = "water_tunnel"
date = 2026-01-02
description = "planned"

[loadcell]
model = "DMI D6095XA"
rate_hz = 500.0

[motion]
rate_hz = 65.0
feedback = false
"""

RUNS = [("p001", 0.0, -30.0, -60.0, 0.62, 1.2, 2), ("zz-7", 0.12, 5.0, -25.0, 0.4, 2.9, 3),
        ("p010", 0.3, -48.5, -79.0, 0.5, 4.0, 2)]


def _plan(tmp_path, runs=RUNS):
    text = PLAN
    for rid, u, h, k, f, phi, cyc in runs:
        text += (f'\n[[runs]]\nid = "{rid}"\nflow_speed_mps = {u}\ntheta_h_min_deg = {h}\ntheta_h_max_deg = -100.0\n'
                 f"theta_k_min_deg = 80.0\ntheta_k_max_deg = {k}\nfrequency_hz = {f}\nphi_rad = {phi}\n"
                 f"alpha_rad = 0.0\ncycles = {cyc}\n")
    path = tmp_path / "plans" / "next.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def test_the_tunnel_measures_exactly_the_planned_runs(tmp_path, capsys):
    plan = _plan(tmp_path)
    out = generate_tunnel(tmp_path / "raw" / "next", plan=plan, seed=3)
    doc = tomllib.loads((out / "campaign.toml").read_text())
    assert [r["id"] for r in doc["runs"]] == [r[0] for r in RUNS]
    for r, (rid, u, h, k, f, phi, cyc) in zip(doc["runs"], RUNS, strict=True):
        assert (r["flow_speed_mps"], r["theta_h_min_deg"], r["theta_k_max_deg"], r["frequency_hz"], r["phi_rad"],
                r["cycles"]) == (u, h, k, f, phi, cyc)
        assert r["loadcell"] == f"runs/{rid}.loadcell.csv" and (out / r["motion"]).is_file()
    truth = json.loads((out / "truth.json").read_text())
    # the controller ran each run's cycles: its log spans cycles / f plus the ease-in and -out
    for rid, *_, f, _phi, cyc in RUNS:
        assert truth["runs"][rid]["controller"]["end_s"] - truth["runs"][rid]["controller"]["first_edge_s"] == \
            pytest.approx(cyc / f + 0.4, abs=0.05)
    assert main(["campaign", "validate", str(out)]) == 0
    assert "valid (water_tunnel, 3 runs checked)" in capsys.readouterr().err


def test_a_plan_validates_as_files_pending_not_a_crash(tmp_path, capsys):
    folder = tmp_path / "next"
    folder.mkdir()
    (folder / "campaign.toml").write_text(_plan(tmp_path).read_text())
    assert main(["campaign", "validate", str(folder)]) == 2
    err = capsys.readouterr().err
    assert err.count("missing 'loadcell' file") == 3
    assert "files pending" in err and "Traceback" not in err


def test_a_bad_plan_is_one_line_naming_the_run(tmp_path):
    plan = _plan(tmp_path, RUNS[:1] + [("p002", 0.1, -30.0, -60.0, 0.0, 1.0, 2)])
    with pytest.raises(ContractError, match="run p002"):
        generate_tunnel(tmp_path / "raw" / "bad", plan=plan)
    assert main(["virtual-lab", "tunnel", str(tmp_path / "raw" / "bad"), "--plan", str(tmp_path / "nope.toml")]) != 0
