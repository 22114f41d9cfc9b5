import json

import pytest

from workbench import report
from workbench.cli import main
from workbench.report.pool import _improvement_table


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
    assert "| EF | 1 | -12.5 | -33.0 | 0.610 |" in md
    # objectives named per task, with units
    assert "-Y impulse f1 (N s)" in md and "time to 2 m f3 (s)" in md and "path length f1" not in md
    assert "No trial scores yet." in md and "No drag fit yet." in md
    assert "Not converged" not in md


def test_report_says_when_a_diagnosis_ran_out_of_rounds(tmp_path):
    ds = tmp_path / "datasets"
    _fake_results(ds)
    path = ds / "diagnosis/demo-tunnel-ef/diagnosis.json"
    doc = json.loads(path.read_text())
    doc["selection_budget"] = {"max_effects": 8, "converged": False, "acceptable_left": [
        {"effect": "link_weight_buoyancy", "label": "link_weight_buoyancy", "t": 19.1, "p": 1e-9, "max_gain": 0.03}],
        "note": "the selection stopped at its budget of 8 rounds with 1 acceptable candidate(s) left: "
                "link_weight_buoyancy (t 19.1)"}
    _write(path, doc)
    md = report.render_markdown(report.collect(ds, with_mlflow=False), tmp_path / "out")
    assert "**Not converged:** the selection stopped at its budget of 8 rounds" in md
    assert "link_weight_buoyancy (t 19.1)" in md


def test_report_verb_writes_html_and_markdown(tmp_path):
    ds = tmp_path / "datasets"
    _fake_results(ds)
    out = tmp_path / "rep"
    assert main(["report", "--datasets", str(ds), "--out", str(out), "--no-mlflow"]) == 0
    page = (out / "report.html").read_text()
    assert page.startswith("<!doctype html>") and "added_mass_error" in page and "<script" not in page
    assert (out / "report.md").is_file()
    head = json.loads((out / "headline.json").read_text())
    assert head["lstm_over_ef_mse"]["fz"] == 0.25  # 0.01 / 0.04
    assert head["best_S"] == {"straight-ef": 34.98}
    assert head["diagnosis"]["effects"] == 1
    assert "drag_c2" not in head and "pool_time_s" not in head  # results not there are left out
    # people-sized: results only, no paths or timings, at most a few dozen numbers
    flat = json.dumps(head)
    assert "/" not in flat.replace("straight-ef", "") and "seconds" not in flat
    assert sum(len(v) if isinstance(v, dict) else 1 for v in head.values()) <= 40


# slow (docs/testing.md): 7.7 s alone, most of it creating MLflow's sqlite store (measured 29 Nov 2026)
@pytest.mark.slow
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
        # a pruned trial ends KILLED, tagged as tune tags it: the link says pruned, not killed
        mlflow.set_experiment("fed-lstm-tune")
        mlflow.start_run(run_name="trial 1")
        mlflow.set_tag("state", "pruned")
        mlflow.end_run("KILLED")
    finally:
        mlflow.set_tracking_uri(None)
    sec = report.mlflow_section(uri, "http://127.0.0.1:5055")
    labels = [label for label, _ in sec.links]
    assert labels == ["fed-lstm: lstm 64x2 L32 (finished)", "fed-lstm-tune: trial 1 (pruned)", "fed-lstm-tune: trial 0 (finished)",
                      "optimize: straight-ef (finished)", "my-own: by hand (finished)"]
    assert all(url.startswith("http://127.0.0.1:5055/#/experiments/") for _, url in sec.links)


def _pool_results(ds, cap_s, lstm_pred, ef_pred, lstm_times, ef_times):
    import csv

    for model in ("ef", "lstm"):
        pred = lstm_pred if model == "lstm" else ef_pred
        _write(ds / f"gaits/turn-{model}.json", {
            "task": "turn", "model": model,
            "settings": {"task": {"task": "turn", "cap_s": cap_s, "target_yaw_deg": 360.0}},
            "solutions": [{"rank": i + 1, "params": {}, "objectives": {"f1": 0.5, "f2": 0.0, "f3": p}, "score": 1.0}
                          for i, p in enumerate(pred)]})
    (ds / "scores/pool").mkdir(parents=True, exist_ok=True)
    _write(ds / "scores/pool/summary.json", {"comparison": {"models": {}}})
    with open(ds / "scores/pool/scores.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["trial_id", "model", "solution", "task", "time_s", "mae_x_m", "radius_m", "completed"])
        for label, times in (("FED-LSTM", lstm_times), ("EF", ef_times)):
            for i, t in enumerate(times):
                w.writerow([f"{label}-{i}", label, i + 1, "turn", t, "", 0.1, str(t < 60).lower()])


def test_pool_verdict_says_why_the_lstm_gaits_lose(tmp_path):
    ds = tmp_path / "datasets"
    # the FED-LSTM predicted 20 s and 22 s for its gaits; they took 50 s and 60 s (unfinished) in the pool,
    # while the EF's predictions (40 s, 44 s) were close to its pool times (41 s, 45 s)
    _pool_results(ds, 60.0, [20.0, 22.0], [40.0, 44.0], [50.0, 60.0], [41.0, 45.0])
    (text,) = report.pool_verdict(ds, ds / "scores/pool")
    assert "turn: FED-LSTM gaits do not beat EF gaits" in text
    assert "55.0 s (1/2 finished) against 43.0 s (2/2)" in text
    assert "pool minus prediction: +34.0 s and +1.0 s" in text
    assert "optimistic about its own gaits" in text and "optimiser found no better gait" not in text
    md = report.render_markdown(report.collect(ds, with_mlflow=False), tmp_path / "out")
    assert "do not beat EF gaits" in md


def test_pool_verdict_flags_gaits_optimised_for_another_task(tmp_path):
    ds = tmp_path / "datasets"
    # LSTM gaits lose, and both were optimised with a 12 s cap: predictions are not comparable
    _pool_results(ds, 12.0, [8.0, 9.0], [9.0, 10.0], [60.0, 60.0], [52.0, 58.0])
    (text,) = report.pool_verdict(ds, ds / "scores/pool")
    assert "do not beat" in text and "cap_s 12 instead of 60" in text
    assert "pool minus prediction" not in text
    # and a win on another task's gaits is reported with the caveat
    _pool_results(ds, 12.0, [8.0, 9.0], [9.0, 10.0], [40.0, 41.0], [52.0, 58.0])
    (text,) = report.pool_verdict(ds, ds / "scores/pool")
    assert "gaits beat EF gaits" in text and "Caveat:" in text


def test_sensitivity_section_averages_total_indices_over_gaits(tmp_path):
    ds = tmp_path / "datasets"
    names = ["extra_yaw_damping_nms", "yaw_inertia_kgm2"]
    factors = [{"name": "extra_yaw_damping_nms", "low": 0.0, "high": 0.02, "unit": "N m s"},
               {"name": "yaw_inertia_kgm2", "low": 0.022, "high": 0.045, "unit": "kg m^2"}]

    def idx(st):
        return {"first_order": dict(zip(names, st, strict=True)), "total_order": dict(zip(names, st, strict=True))}

    _write(ds / "reports/sensitivity/turn-ef/sensitivity.json", {
        "task": "turn", "n_simulations": 64, "factors": factors,
        "indices": {"#1": idx([0.9, 0.1]), "#2": idx([0.5, 0.3]), "ranking_kendall_tau": idx([0.2, 0.6])},
        "ranking": {"kendall_tau_mean": 0.81, "kendall_tau_min": 0.36, "nominal_best_stays_best_fraction": 1.0},
        "unconverged_samples": {"#3": [4, 7]}})
    sec = report.sensitivity_section(ds)
    (caption, header, rows), = sec.tables
    assert rows[0][0] == "extra_yaw_damping_nms" and rows[0][2] == "0.700" and rows[0][3] == "0.900"
    assert rows[1][2] == "0.200" and rows[1][4] == "0.600"
    assert "stays best in 100 %" in sec.paragraphs[0] and "depend most on extra_yaw_damping_nms" in sec.paragraphs[0]
    assert "Unconverged samples (not scored): 2" in sec.paragraphs[0]
    assert "No sensitivity study yet" in report.render_markdown(report.collect(tmp_path / "empty", with_mlflow=False),
                                                               tmp_path)


def test_pool_verdict_when_no_turn_finishes(tmp_path):
    ds = tmp_path / "datasets"
    # neither model finishes; the FED-LSTM predicted 45 s for its gaits, the EF 60 s (unfinished too)
    _pool_results(ds, 60.0, [45.0, 45.0], [60.0, 60.0], [60.0, 60.0], [60.0, 60.0])
    (text,) = report.pool_verdict(ds, ds / "scores/pool")
    assert "neither model's gaits finished the task within 60 s" in text
    assert "mean yaw torque cancels" in text
    assert "FED-LSTM predicted its gaits to finish in 45.0 s" in text and "EF predicted its gaits" not in text


def test_report_for_a_reader_tables_captions_and_unfinished_trials(tmp_path):
    ds = tmp_path / "datasets"
    # LSTM gaits 20 s / 22 s predicted; in the pool one finished in 50 s, one did not (60 s cap)
    _pool_results(ds, 60.0, [20.0, 22.0], [40.0, 44.0], [50.0, 60.0], [41.0, 45.0])
    for sub in ("gaits/turn-ef", "gaits/turn-lstm", "scores/pool/plots"):
        (ds / sub).mkdir(parents=True, exist_ok=True)
    for f in ("gaits/turn-ef/trajectories.png", "gaits/turn-lstm/trajectories.png", "scores/pool/plots/boxplots.png"):
        (ds / f).write_bytes(b"png")
    md = report.render_markdown(report.collect(ds, with_mlflow=False), tmp_path / "out")
    # an unfinished trial is not shown as a 60 s time
    assert "| turn | FED-LSTM | 2 | not finished within 60 s |" in md
    assert "| turn | FED-LSTM | 1 | 50.0 |" in md
    # the pool comparison is a table of the report, not a pasted markdown page with its own title
    assert "# Open-water trials:" not in md
    # captions say what a figure shows (and two figures of the same name differ by task and model)
    assert "Simulated 60 s paths of the retained gaits, start at the origin (turn task, EF)" in md
    assert "Simulated 60 s paths of the retained gaits, start at the origin (turn task, FED-LSTM)" in md
    assert "![trajectories]" not in md
    html = report.render_html(report.collect(ds, with_mlflow=False), tmp_path / "out")
    assert "<figcaption>Pool-trial scores per model and task" in html
    assert "turn task" in report.caption(ds / "gaits/turn-ef/pareto.png")


def test_unfinished_trials_are_drawn_apart_in_the_pool_boxplots(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import polars as pl

    from workbench.trials.plots import plot_boxplots

    scores = pl.DataFrame({"trial_id": ["a", "b", "c", "d"], "model": ["EF", "EF", "FED-LSTM", "FED-LSTM"],
                           "solution": [1, 2, 1, 2], "task": ["turn"] * 4, "time_s": [41.0, 60.0, 60.0, 60.0],
                           "mae_x_m": [None] * 4, "radius_m": [0.1, 0.2, 0.15, 0.12],
                           "completed": [True, False, False, False]})
    out = plot_boxplots(scores, tmp_path / "box.png", baseline="EF")
    assert out.stat().st_size > 10_000


def test_improvement_table_survives_missing_improvements():
    # score-trials leaves the improvement empty where the baseline is zero or missing
    summary = {"comparison": {"baseline": "EF", "models": {"FED-LSTM": {"straight": {
        "best": {"time_s": {"EF": 0.0, "FED-LSTM": 12.0, "improvement": None}},
        "mean": {"mae_x_m": {"EF": 0.4, "FED-LSTM": 0.2, "improvement": 0.5}}}}}}}
    caption, header, rows = _improvement_table(summary)
    assert ["straight", "FED-LSTM", "best", "T (s)", "0.000", "12.000", "-"] in rows
    assert rows[-1][-1] == "+50.0 %"
