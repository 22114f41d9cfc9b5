import json

from workbench import report
from workbench.cli import main


def _write(path, obj):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj))


def _fake_results(ds):
    ch = ["fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm"]
    _write(ds / "metrics/leg_models.json", {
        m: {"mse": {c: v for c in ch}, "r2": {c: 0.8 for c in ch},
            "mse_by_flow_speed": {"0.10": {c: v for c in ch}, "0.20": {c: 2 * v for c in ch}}}
        for m, v in (("ef", 0.04), ("lstm", 0.01))})
    _write(ds / "gaits/straight-ef.json", {"task": "straight", "model": "ef", "solutions": [
        {"rank": 1, "params": {"theta_h_min_deg": -12.5, "theta_k_max_deg": -33.0, "frequency_hz": 0.61,
                               "alpha_rad": [0, 3.1, 1.5, 4.6]},
         "objectives": {"f1": -1.5, "f2": 0.02, "f3": 18.2}, "score": 34.98}]})
    _write(ds / "diagnosis/demo-tunnel-ef/diagnosis.json", {
        "model": "ef", "channels": ch, "mse_before": {c: 0.05 for c in ch}, "mse_after": {c: 0.01 for c in ch},
        "effects": [{"name": "added_mass_error", "channels": ["fy_n", "fz_n"], "params": {"delta_kg": -0.07},
                     "evidence": "residual in phase with the acceleration", "heldout_mse_reduction": 0.61}],
        "unexplained": [{"kind": "narrowband", "channels": ["fz_n"], "frequency_hz": 4.1,
                         "evidence": "peak locked to nothing"}]})


def test_report_ties_results_together(tmp_path):
    ds = tmp_path / "datasets"
    _fake_results(ds)
    secs = report.collect(ds, with_mlflow=False)
    md = report.render_markdown(secs, tmp_path / "out")
    # the LSTM/EF ratio is computed, not copied: 0.01/0.04 = 0.25
    assert "| 0.10 | 0.250 | 0.250 | 0.250 |" in md
    assert "added_mass_error" in md and "delta_kg=-0.070" in md
    assert "4.10 Hz" in md
    assert "| straight | ef | 1 | -12.5 | -33.0 | 0.610 |" in md
    assert "No trial scores yet." in md and "No drag fit yet." in md


def test_report_verb_writes_html_and_markdown(tmp_path):
    ds = tmp_path / "datasets"
    _fake_results(ds)
    out = tmp_path / "rep"
    assert main(["report", "--datasets", str(ds), "--out", str(out), "--no-mlflow"]) == 0
    page = (out / "report.html").read_text()
    assert page.startswith("<!doctype html>") and "added_mass_error" in page and "<script" not in page
    assert (out / "report.md").is_file()
    head = json.loads((out / "headline.json").read_text())
    assert head["leg_models"]["lstm_over_ef_mse"]["fz_n"] == 0.25  # 0.01 / 0.04
    assert head["gaits_best_score"] == {"straight-ef": 34.98}
    assert head["diagnosis"]["demo-tunnel-ef"]["effects"] == 1
    assert "drag" not in head and "trials_mean_improvement" not in head  # results not there are left out


def test_mlflow_links_cover_every_pipeline_experiment_in_flow_order(tmp_path):
    import mlflow

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    mlflow.set_tracking_uri(uri)
    try:
        for exp, run in (("optimize", "straight-ef"), ("fed-lstm", "lstm 64x2 L32"), ("fed-lstm-tune", "trial 0"),
                         ("my-own", "by hand")):
            mlflow.set_experiment(exp)
            with mlflow.start_run(run_name=run):
                mlflow.log_metric("x", 1.0)
    finally:
        mlflow.set_tracking_uri(None)
    sec = report.mlflow_section(uri, "http://127.0.0.1:5055")
    labels = [label for label, _ in sec.links]
    assert labels == ["fed-lstm: lstm 64x2 L32 (finished)", "fed-lstm-tune: trial 0 (finished)",
                      "optimize: straight-ef (finished)", "my-own: by hand (finished)"]
    assert all(url.startswith("http://127.0.0.1:5055/#/experiments/") for _, url in sec.links)
