"""The two commands end to end on a small synthetic pool: outputs have the contract's shape."""

import json

import cv2
import polars as pl
import pytest

from workbench.cli import main

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def scored_cli(tmp_path_factory):
    root = tmp_path_factory.mktemp("cli")
    pool, out = root / "syn-pool", root / "scores"
    assert main(["virtual-lab", "pool", str(pool), "--synthetic", "--best", "1", "--fps", "8"]) == 0
    assert main(["score-trials", str(pool), "--out", str(out), "--workers", "1"]) == 0
    return pool, out


def test_pool_cli_writes_a_trials_folder(scored_cli):
    pool, _ = scored_cli
    text = (pool / "trials.toml").read_text()
    assert 'schema = "workbench/trials@1"' in text and 'id = "syn-pool"' in text
    assert len(list((pool / "videos").glob("*.mp4"))) == 4


def test_scores_csv_and_summary_shape(scored_cli):
    pool, out = scored_cli
    df = pl.read_csv(out / "scores.csv")
    assert df.columns == ["trial_id", "model", "solution", "task", "time_s", "mae_x_m", "radius_m", "completed"]
    assert df.height == 4
    assert df.filter(pl.col("task") == "turn")["mae_x_m"].null_count() == 2
    assert df.filter(pl.col("task") == "straight")["radius_m"].null_count() == 2
    s = json.loads((out / "summary.json").read_text())
    for model in ("EF", "FED-LSTM"):
        for task, names in (("straight", ("time_s", "mae_x_m")), ("turn", ("time_s", "radius_m"))):
            for name in names:
                assert set(s["by_model"][model][task][name]) == {"mean", "median", "min", "max"}
    comp = s["comparison"]
    assert comp["baseline"] == "EF"
    best = comp["models"]["FED-LSTM"]["straight"]["best"]["time_s"]
    assert best["improvement"] == pytest.approx((best["EF"] - best["FED-LSTM"]) / best["EF"])
    assert s["failed"] == [] and s["n_scored"] == 4
    truth = json.loads((pool / "truth.json").read_text())["trials"]
    for row in df.iter_rows(named=True):
        assert abs(row["time_s"] - truth[row["trial_id"]]["scores"]["time_s"]) <= 1 / 8 + 0.1


def test_plots_trajectories_and_overlays(scored_cli):
    _, out = scored_cli
    for name in ("trajectories.png", "boxplots.png"):
        assert (out / "plots" / name).stat().st_size > 10_000
    assert len(list((out / "plots" / "trials").glob("*.png"))) == 4
    tr = pl.read_parquet(out / "trajectories" / "ef-straight-1.parquet")
    for col in ("time_s", "x_m", "y_m", "X_m", "Y_m", "heading_change_deg", "detected", "filled"):
        assert col in tr.columns
    assert tr.filter(pl.col("time_s").abs() < 1e-9).height <= 1
    cap = cv2.VideoCapture(str(out / "overlays" / "ef-straight-1.mp4"))
    assert cap.isOpened() and cap.get(cv2.CAP_PROP_FRAME_COUNT) > 50
    assert "| EF_1 |" in (out / "comparison.md").read_text()


def test_help_teaches_with_examples(capsys):
    with pytest.raises(SystemExit):
        main(["score-trials", "--help"])
    assert "examples:" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["virtual-lab", "pool", "--help"])
    assert "--synthetic" in capsys.readouterr().out
