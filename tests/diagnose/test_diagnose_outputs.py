"""What diagnose leaves behind: diagnosis.json per contract, the augmented model, the report, MLflow, the CLI."""

import json

import numpy as np
import pytest
from diag_helpers import campaign

from workbench.cli import main
from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose.augmented import AugmentedLegModel
from workbench.diagnose.loop import diagnose
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.legmodel import LegForceModel, load_leg_model

PAIR = ("servo_lag:tau_s=0.04", "sensor_drift:rate_fz_n_per_s=0.002")


@pytest.fixture(scope="module")
def pair_diagnosis(vl_frames):
    return diagnose(vl_frames(PAIR, n_sets=10), EmpiricalFormula(), "ef")


@pytest.mark.slow
def test_diagnosis_json_follows_the_contract(pair_diagnosis):
    j = json.loads(json.dumps(pair_diagnosis.to_json()))
    assert j["model"] == "ef"
    assert j["channels"] == list(WRENCH_CHANNELS)
    for key in ("mse_before", "mse_after"):
        assert set(j[key]) == set(WRENCH_CHANNELS)
        assert all(isinstance(v, float) and v >= 0 for v in j[key].values())
    assert [e["name"] for e in j["effects"]] == ["servo_lag", "sensor_drift"]
    for e in j["effects"]:
        assert set(e) >= {"name", "channels", "params", "evidence", "heldout_mse_reduction"}
        assert isinstance(e["evidence"], str) and e["evidence"].endswith(".")
        assert 0 < e["heldout_mse_reduction"] <= 1
        assert set(e["channels"]) <= set(WRENCH_CHANNELS)
        for k, (lo, hi) in e["ci95"].items():
            assert lo <= e["params"][k] <= hi
    assert j["effects"][1]["channels"] == ["fz_n"]
    assert isinstance(j["unexplained"], list)
    assert j["heldout_runs"] and j["n_train_runs"] > len(j["heldout_runs"])


@pytest.mark.slow
def test_report_is_returned_as_text_and_png_bytes_not_written(pair_diagnosis, tmp_path, monkeypatch):
    import re

    from workbench.diagnose.report import render_report

    monkeypatch.chdir(tmp_path)
    files = render_report(pair_diagnosis)
    assert list(tmp_path.iterdir()) == []                      # nothing written
    md = files["report.md"]
    assert isinstance(md, str) and md.startswith("# Diagnosis of `ef`")
    links = re.findall(r"!\[[^]]*\]\(([^)]+)\)", md)
    pngs = {k for k, v in files.items() if k != "report.md"}
    # every figure the text links is returned, and every returned figure is linked, as a whole PNG
    assert set(links) == pngs >= {"figures/spectra.png", "figures/effect_servo_lag.png", "figures/effect_sensor_drift.png"}
    for name in pngs:
        assert files[name][:8] == b"\x89PNG\r\n\x1a\n" and files[name][-8:-4] == b"IEND"
    assert set(render_report(pair_diagnosis, figures=False)) == {"report.md"}


@pytest.mark.slow
def test_augmented_model_is_a_leg_force_model_and_reproduces_mse_after(pair_diagnosis, tmp_path):
    d = pair_diagnosis
    aug = d.augmented
    assert isinstance(aug, LegForceModel)
    path = aug.save(tmp_path / "augmented_model.json")
    for spec in (f"augmented:{tmp_path}", str(path)):
        loaded = load_leg_model(spec)
        assert isinstance(loaded, AugmentedLegModel)
        assert [a.name for a in loaded.config.actives] == ["servo_lag", "sensor_drift"]
    # predict the held-out runs from scratch (motion + time since the first edge) and recompute MSE
    errs = []
    for r in d.residuals_after:
        if not r.heldout:
            continue
        from workbench.diagnose.data import derivative4
        from workbench.hydro.motion import LegMotion

        m = LegMotion.from_arrays(r.dt_s, r.theta_h, r.theta_k, r.omega_h, r.omega_k, r.flow,
                                  derivative4(r.omega_h[None], r.dt_s), derivative4(r.omega_k[None], r.dt_s))
        w = loaded.wrench(m, time_s=r.time_s)[0]
        errs.append((r.measured - w)[r.fit])
    mse = (np.concatenate(errs) ** 2).mean(axis=0)
    for c, v in zip(WRENCH_CHANNELS, mse, strict=False):
        assert v == pytest.approx(d.mse_after[c], rel=1e-6)
    # the physical leg keeps the servo lag and drops the load cell's drift
    phys = loaded.physical()
    assert [a.name for a in phys.config.actives] == ["servo_lag"]
    assert phys.wrench(m).shape == w[None].shape


@pytest.mark.slow
def test_cli_writes_everything_and_logs_to_mlflow(tmp_path):
    camp = campaign(tmp_path, ("sensor_drift:rate_fz_n_per_s=0.002",), n_sets=8)
    out = tmp_path / "diag"
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    rc = main(["diagnose", "--campaign", str(camp), "--model", "ef", "--out", str(out), "--tracking-uri", uri])
    assert rc == 0
    doc = json.loads((out / "diagnosis.json").read_text())
    assert [e["name"] for e in doc["effects"]] == ["sensor_drift"]
    assert (out / "augmented_model.json").is_file()
    report = (out / "report.md").read_text()
    assert "sensor_drift" in report and "![spectra](figures/spectra.png)" in report
    for png in ("residuals", "spectra", "correlations", "dependence", "effect_sensor_drift"):
        assert (out / "figures" / f"{png}.png").stat().st_size > 1000
    import mlflow

    mlflow.set_tracking_uri(uri)
    runs = mlflow.search_runs(experiment_names=["diagnose"])
    assert len(runs) == 1
    assert runs.iloc[0]["tags.effects"] == "sensor_drift"
    assert runs.iloc[0]["metrics.effect.sensor_drift.rate_fz_n_per_s"] == pytest.approx(0.002, rel=0.2)


@pytest.mark.slow
def test_cli_reads_a_processed_file(tmp_path):
    from workbench.ingest import ingest_campaign, write_processed

    camp = campaign(tmp_path, (), n_sets=6)
    pq = tmp_path / "p.parquet"
    write_processed(ingest_campaign(camp), pq)
    out = tmp_path / "d"
    assert main(["diagnose", "--processed", str(pq), "--out", str(out), "--no-mlflow", "--no-figures"]) == 0
    assert json.loads((out / "diagnosis.json").read_text())["effects"] == []


def test_cli_refuses_bad_input_in_one_line_and_leaves_the_previous_result(tmp_path, capsys):
    camp = campaign(tmp_path, (), n_sets=6)
    out = tmp_path / "d"
    out.mkdir()
    (out / "diagnosis.json").write_text('{"previous": "result"}')
    before = (out / "diagnosis.json").read_text()
    # bad input: one line naming the file, exit status 2, previous result intact
    assert main(["diagnose", "--processed", str(tmp_path / "missing.parquet"), "--out", str(out), "--no-mlflow"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error:") and "missing.parquet" in err[-1] and len(err[-1].splitlines()) == 1
    assert main(["diagnose", "--campaign", str(camp), "--model", "no-such-model", "--out", str(out),
                 "--no-mlflow"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error:") and "no-such-model" in err[-1]
    assert (out / "diagnosis.json").read_text() == before


@pytest.mark.slow
def test_a_virtual_campaign_shows_its_truth_beside_the_fitted_parameters(tmp_path):
    camp = campaign(tmp_path, (), truth="rich", n_sets=8)
    out = tmp_path / "diag"
    assert main(["diagnose", "--campaign", str(camp), "--model", "ef", "--out", str(out), "--no-mlflow",
                 "--no-figures"]) == 0
    doc = json.loads((out / "diagnosis.json").read_text())
    shown = [e for e in doc["effects"] if "virtual_truth" in e]
    assert shown, [e["name"] for e in doc["effects"]]
    # the truth's own numbers (virtual_lab.yaml / physics.py): C_N90 1.17, the EF's C_R 0.7 taken out
    truth = json.loads((camp / "truth.json").read_text())["truth"]["params"]
    for e in shown:
        if e["name"] == "normal_force_law":
            assert e["virtual_truth"]["c_n90"] == pytest.approx(truth.get("c_n90", 1.17))
        assert set(e["virtual_truth"]) & set(e["params"])  # the truth speaks of the fitted parameters
    assert "| virtual truth |" in (out / "report.md").read_text()
    # a real campaign (no truth.json) gets no such key
    (camp / "truth.json").rename(tmp_path / "truth.json")
    assert main(["diagnose", "--campaign", str(camp), "--model", "ef", "--out", str(out), "--no-mlflow",
                 "--no-figures"]) == 0
    assert not any("virtual_truth" in e for e in json.loads((out / "diagnosis.json").read_text())["effects"])
