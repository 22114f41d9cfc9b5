"""The virtual pool and score-trials with three models (EF, the 32-tick and the 16-tick FED-LSTM; issue 14.6)."""

import json

import pytest

from workbench.cli import main
from workbench.virtual_lab.pool import (
    PoolSettings,
    PoolTrial,
    generate_pool,
    model_display_label,
    simulated_trials,
    straight_path,
)

#: small fast videos (as the trials tests use): 480x270, 15 fps, no occlusions
SMALL = dict(width_px=480, height_px=270, fps=15.0, start_s=0.53, post_s=1.0, occlusion_fraction=0.0, workers=1,
             glare_patches=1, straight_start=(1.2, 1.2, 0.0), turn_start=(1.2, 2.5, 20.0))


def test_labels_of_any_model():
    assert [model_display_label(m) for m in ("ef", "lstm", "lstm16", "lstm24", "gru")] == \
        ["EF", "FED-LSTM", "FED-LSTM-16", "FED-LSTM-24", "GRU"]
    # the parameter file's labels win; models it does not name keep theirs
    labels = {"ef": "EF", "lstm": "FED-LSTM (32 ticks)"}
    assert model_display_label("lstm", labels) == "FED-LSTM (32 ticks)"
    assert model_display_label("lstm16", labels) == "FED-LSTM-16"


def _gait_file(folder, task, model, theta_h_min):
    sols = [{"rank": r, "params": {"theta_h_min_deg": theta_h_min - 5 * r, "theta_k_max_deg": -50.0,
                                   "frequency_hz": 0.5, "alpha_rad": [0.0, 3.14, 3.14, 0.0]},
             "objectives": {"f1": 0.0, "f2": 0.0, "f3": 0.0}, "score": float(r)} for r in (1, 2)]
    (folder / f"{task}-{model}.json").write_text(json.dumps({"task": task, "model": model, "solutions": sols}))


def test_simulated_trials_of_three_models_in_the_files_order(tmp_path):
    for model, th in (("ef", -20.0), ("lstm", -10.0), ("lstm16", 0.0)):
        _gait_file(tmp_path, "straight", model, th)
    s = PoolSettings(models=("lstm16", "ef", "lstm"), tasks=("straight",), best=1, physics="ef",
                     robot_params="/nonexistent.yaml", model_labels={"ef": "EF", "lstm": "FED-LSTM"})
    trials = simulated_trials(tmp_path, s)
    assert [t.id for t in trials] == ["lstm16-straight-1", "ef-straight-1", "lstm-straight-1"]
    assert [t.model for t in trials] == ["FED-LSTM-16", "EF", "FED-LSTM"]
    # three different gaits, three different swims (none a copy of another)
    ends = [round(float(t.y_m[-1]), 6) for t in trials]
    assert len(set(ends)) == 3 and min(ends) > 0.05


@pytest.mark.slow
def test_score_trials_compares_three_models(tmp_path):
    """Render three models' straight runs at planted speeds, score them, and compare all three with EF."""
    from workbench.gait.compare import seq_len_comparison

    speeds = {"EF": 0.20, "FED-LSTM": 0.30, "FED-LSTM-16": 0.25}     # m/s: finishes 2 m in 10, 6.7 and 8 s
    trials = [PoolTrial(f"{label.lower()}-straight-1", "straight", label, 1,
                        *straight_path(speed_mps=v, drift_deg=0.0, duration_s=14)) for label, v in speeds.items()]
    pool, out = tmp_path / "pool3", tmp_path / "scores3"
    generate_pool(pool, trials, settings=PoolSettings(**SMALL, seed=5), progress=False)
    assert main(["score-trials", str(pool), "--out", str(out), "--workers", "1"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["by_model"]) == set(speeds)
    comp = summary["comparison"]
    assert comp["baseline"] == "EF" and set(comp["models"]) == {"FED-LSTM", "FED-LSTM-16"}
    times = {m: summary["by_model"][m]["straight"]["time_s"]["min"] for m in speeds}
    truth = json.loads((pool / "truth.json").read_text())["trials"]
    for m in speeds:   # the rendered truth's finishing time, within a frame and 0.1 s
        assert times[m] == pytest.approx(truth[f"{m.lower()}-straight-1"]["scores"]["time_s"], abs=1 / 15 + 0.1)
    assert times["FED-LSTM"] < times["FED-LSTM-16"] < times["EF"]   # the planted speeds' order
    for m in ("FED-LSTM", "FED-LSTM-16"):
        imp = comp["models"][m]["straight"]["best"]["time_s"]["improvement"]
        assert imp == pytest.approx((times["EF"] - times[m]) / times["EF"])
    md = (out / "comparison.md").read_text()
    assert all(f"| {m}_1 |" in md for m in speeds)
    assert "improvement of FED-LSTM over EF" in md and "improvement of FED-LSTM-16 over EF" in md
    # the report's table reads the same summary
    table = seq_len_comparison([("lstm", "FED-LSTM (32)"), ("lstm16", "FED-LSTM (16)")], pool_summary=summary)
    row16 = next(line for line in table.splitlines() if line.startswith("| straight | FED-LSTM (16) |"))
    assert f"| 1/1 | {times['FED-LSTM-16']:.1f} |" in row16
