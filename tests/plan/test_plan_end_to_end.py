"""Ensemble -> plan -> virtual measurement, on a small synthetic campaign (real training, real files)."""

from __future__ import annotations

import json
import math
import tomllib

import numpy as np
import pytest


@pytest.fixture(scope="module")
def ensemble_dir(tmp_path_factory):
    from learn_helpers import make_frame, tiny_config

    from workbench.commands.train_ensemble import write_ensemble
    from workbench.learn.ensemble import load_ensemble, train_ensemble

    d = tmp_path_factory.mktemp("ens")
    frame = make_frame(speeds=(0.0, 0.1, 0.2), freqs=(0.4, 0.6))
    frame.write_parquet(d / "synth.parquet")
    cfg = tiny_config([d / "synth.parquet"], d, **{"tracking.enabled": False, "model_dir": None,
                                                    "data.seq_len": 8, "trainer.max_epochs": 1})
    rec, files = train_ensemble(cfg, members=3, first_seed=5)
    write_ensemble(d / "ensemble", files)
    ens = load_ensemble(d / "ensemble")
    assert len(ens.members) == 3 and [m["seed"] for m in rec["members"]] == [5, 6, 7]
    return d / "ensemble", rec


@pytest.mark.slow
def test_ensemble_reports_calibration_measured_on_held_out_sets(ensemble_dir):
    _, rec = ensemble_dir
    cal = rec["calibration"]
    # the scale is fitted on the validation runs (cross-conformal by run); two val-fitted alternatives beside it
    assert cal["fitted_on"] == "val" and cal["val_runs"] >= 2 and "leave-one-run-out" in cal["method"]
    assert set(cal["scale_pooled"]) == set(cal["coverage_test_pooled_scale"]) == set(rec["scale"])
    assert set(cal["scale_run_quantile"]) == set(cal["coverage_test_run_quantile_scale"]) == set(rec["scale"])
    if cal["val_runs"] >= 3:  # the leave-one-run-out search reached 90 % on validation, at a level of 0.9 or more
        assert all(v >= 0.9 for v in cal["coverage_val_loro"].values())
        assert all(0.9 <= v <= 1 for v in cal["quantile_level"].values())
    assert all(v > 0.8 for v in cal["coverage_val_after"].values())
    assert set(cal["coverage_test_after"]) == {"fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm"}
    assert all(0 <= v <= 1 for v in cal["coverage_test_before"].values())
    assert rec["split"]["counts"]["test"] > 0


@pytest.mark.slow
def test_plan_measure_validate_add(ensemble_dir, tmp_path, capsys, monkeypatch):
    from workbench.cli import main
    from workbench.commands.plan_campaign import plan_from_files
    from workbench.plan.acquisition import RigRanges
    from workbench.plan.planner import PlanSettings
    from workbench.virtual_lab.tunnel import generate_tunnel

    gaits = tmp_path / "straight-x.json"
    gaits.write_text(json.dumps({"task": "straight", "model": "x", "solutions": [
        {"rank": 1, "params": {"theta_h_min_deg": -40.0, "theta_k_max_deg": -70.0, "frequency_hz": 0.6,
                               "alpha_rad": [0.0, math.pi, math.pi, 0.0]}},
        {"rank": 2, "params": {"theta_h_min_deg": -20.0, "theta_k_max_deg": -50.0, "frequency_hz": 0.5,
                               "alpha_rad": [0.0, 1.0, 2.0, 3.0]}}]}))
    diag = tmp_path / "diagnosis.json"
    diag.write_text(json.dumps({"effects": [{"name": "link_inertia", "ambiguous_with": ["wagner_lag"]},
                                            {"name": "wagner_lag"}]}))
    ranges = RigRanges(cycles=2, setup_s=30.0)
    s = PlanSettings(n_candidates=24, swim_s=6.0, region_points_per_cycle=6, points_per_run=4, ranges=ranges)
    out = tmp_path / "plans" / "next-1.toml"
    rec = plan_from_files(ensemble_dir[0], [gaits], 3, out, diagnosis=diag, settings=s, date="2026-01-02")
    doc = tomllib.loads(out.read_text())
    assert doc["id"] == "next-1" and (out.parent / "plan.md").is_file()
    # planning without ``legs`` swims with EF legs, and plan.md says so
    assert "swum with straight-x.json: ef." in (out.parent / "plan.md").read_text()
    runs = doc["runs"]
    # three for the uncertainty, three for the ambiguous pair (zero flow at both frequency ends, top flow)
    assert len(runs) == 6 and rec["n_diagnosis_runs"] == 3
    assert sum(r["flow_speed_mps"] == 0.0 for r in runs) >= 2
    for r in runs:
        assert not any(k in r for k in ("loadcell", "motion", "mcap"))
        assert -50 <= r["theta_h_min_deg"] <= 10 and -80 <= r["theta_k_max_deg"] <= -20
        assert 0.2 <= r["frequency_hz"] <= 0.65 and r["flow_speed_mps"] in ranges.flow_speeds_mps
        assert r["cycles"] == 2
    assert rec["tunnel_s"] == pytest.approx(sum(2 / r["frequency_hz"] + 30.0 for r in runs), rel=1e-3)
    assert rec["total_after"] < rec["total_before"]
    assert np.isfinite([r["gain"] for r in rec["runs"]]).all()
    # measured in a project: validated and added (registered for dvc repro) like any campaign
    project = tmp_path / "proj"
    (project / "datasets" / "raw").mkdir(parents=True)
    (project / "pipelines").mkdir()
    (project / "pipelines" / "campaigns.yaml").write_text("tunnel: []\ntowing: []\n")
    measured = generate_tunnel(project / "datasets" / "raw" / "next-1", plan=out)
    assert main(["campaign", "validate", str(measured)]) == 0
    assert "valid (water_tunnel, 6 runs checked)" in capsys.readouterr().err
    from workbench.ingest.registry import load_registry

    monkeypatch.setenv("WORKBENCH_HOME", str(project))
    assert main(["campaign", "add", str(measured), "--no-dvc"]) == 0
    assert "next-1" in load_registry(project)["tunnel"]
