"""Table IV-style comparison: fed the paper's own Table IV it must reproduce the paper's percentages."""

import pytest

from workbench.trials.compare import (
    SCORE_COLUMNS,
    compare_models,
    comparison_markdown,
    model_statistics,
    pick_baseline,
    relative_improvement,
    scores_frame,
)

# the paper's Table IV: T_S (s), MAE(X) (m), T_T (s), r_T (m) per solution
LSTM = [(21, 0.09, 22, 0.08), (26, 0.06, 28, 0.05), (27, 0.16, 35, 0.07), (26, 0.05, 27, 0.09),
        (25, 0.12, 28, 0.14), (25, 0.11, 21, 0.10), (25, 0.13, 19, 0.10), (24, 0.13, 23, 0.11)]
EF = [(23, 0.17, 42, 0.06), (29, 0.26, 51, 0.02), (16, 0.07, 34, 0.06), (60, 0.51, 50, 0.12),
      (18, 0.24, 38, 0.04), (60, 0.67, 40, 0.05), (25, 0.27, 40, 0.04), (18, 0.26, 33, 0.18)]


def table_iv():
    rows = []
    for name, tab in (("FED-LSTM", LSTM), ("EF", EF)):
        for i, (ts, mae, tt, r) in enumerate(tab, 1):
            rows.append(dict(trial_id=f"{name}-straight-{i}", model=name, solution=i, task="straight", time_s=ts,
                             mae_x_m=mae, completed=ts < 60))
            rows.append(dict(trial_id=f"{name}-turn-{i}", model=name, solution=i, task="turn", time_s=tt,
                             radius_m=r, completed=tt < 60))
    return scores_frame(rows)


def test_paper_table_iv_percentages():
    comp = compare_models(table_iv())
    assert comp["baseline"] == "EF"
    lstm = comp["models"]["FED-LSTM"]
    assert round(100 * lstm["straight"]["best"]["mae_x_m"]["improvement"], 1) == 47.1
    assert round(100 * lstm["straight"]["best"]["time_s"]["improvement"], 1) == 8.7
    assert round(100 * lstm["turn"]["best"]["time_s"]["improvement"], 1) == 47.6
    assert lstm["straight"]["best"]["solution"] == {"FED-LSTM": 1, "EF": 1}
    # over all retained solutions: the means of the table
    assert lstm["straight"]["mean"]["time_s"]["FED-LSTM"] == pytest.approx(24.875)
    assert lstm["straight"]["mean"]["time_s"]["EF"] == pytest.approx(31.125)
    assert lstm["straight"]["mean"]["time_s"]["improvement"] == pytest.approx((31.125 - 24.875) / 31.125)
    assert lstm["turn"]["median"]["radius_m"]["FED-LSTM"] == pytest.approx(0.095)


def test_markdown_table_lists_every_solution_and_the_improvements():
    df = table_iv()
    md = comparison_markdown(df, compare_models(df))
    assert "| FED-LSTM_1 | 21.0 | 0.090 | 22.0 | 0.080 |" in md
    assert "| EF_4 | 60.0* | 0.510 | 50.0 | 0.120 |" in md
    assert "| best solution | +8.7% | +47.1% | +47.6% | -33.3% |" in md


def test_statistics_per_model_and_task():
    stats = model_statistics(table_iv())
    ef = stats["EF"]["straight"]
    assert ef["n"] == 8 and ef["completed"] == 6
    assert ef["time_s"] == {"mean": 31.125, "median": 24.0, "min": 16.0, "max": 60.0}
    assert stats["FED-LSTM"]["turn"]["radius_m"]["max"] == pytest.approx(0.14)
    assert "mae_x_m" not in stats["EF"]["turn"] and "radius_m" not in stats["EF"]["straight"]


def test_best_solution_falls_back_to_the_best_scored_rank():
    df = table_iv().filter(~((table_iv()["model"] == "EF") & (table_iv()["solution"] == 1)))
    best = compare_models(df)["models"]["FED-LSTM"]["straight"]["best"]
    assert best["solution"]["EF"] == 2
    assert best["time_s"]["EF"] == 29


def test_baseline_choice_and_definition():
    assert pick_baseline(["FED-LSTM", "EF"]) == "EF"
    assert pick_baseline(["b", "a"]) == "a"
    assert pick_baseline(["FED-LSTM", "ef"], "EF") == "ef"
    assert pick_baseline(["x"], "EF") is None
    assert relative_improvement(21, 23) == pytest.approx(2 / 23)
    assert relative_improvement(None, 23) is None and relative_improvement(1, 0) is None
    comp = compare_models(table_iv(), baseline="FED-LSTM")
    assert comp["models"]["EF"]["straight"]["best"]["time_s"]["improvement"] == pytest.approx((21 - 23) / 21)


def test_scores_frame_has_the_contract_columns():
    df = table_iv()
    assert tuple(df.columns) == SCORE_COLUMNS
    assert df.filter(df["task"] == "turn")["mae_x_m"].null_count() == 16
