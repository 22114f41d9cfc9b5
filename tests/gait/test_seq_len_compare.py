"""seq_len_comparison: the 32- and 16-tick FED-LSTMs side by side from planted metrics, gait metrics and pool summary."""

import json

import pytest

from workbench.errors import SettingError
from workbench.gait.compare import seq_len_comparison
from workbench.report import seq_len_inputs

MODELS = [("lstm", "FED-LSTM (32)"), ("lstm16", "FED-LSTM (16)")]


def _leg():
    return {"ef": {"mse": {"fy_n": 0.0134, "fz_n": 0.0128, "tx_nm": 2.3e-4}},
            "lstm": {"mse": {"fy_n": 0.0008, "fz_n": 0.0013, "tx_nm": 2.4e-5}, "r2": {"fy_n": 0.978, "fz_n": 0.955,
                                                                                 "tx_nm": 0.980}},
            "lstm16": {"mse": {"fy_n": 0.0012, "fz_n": 0.0026, "tx_nm": 3.6e-5}, "r2": {"fy_n": 0.967, "fz_n": 0.940,
                                                                                   "tx_nm": 0.971}}}


def _row(md, start):
    rows = [line for line in md.splitlines() if line.startswith(start)]
    assert len(rows) == 1, (start, md)
    return [c.strip() for c in rows[0].strip("|").split("|")]


def test_three_views_side_by_side():
    gait = {"lstm": {"straight": {"best_f3": 15.33, "best_score": 34.98}, "turn": {"best_f3": 60.0, "best_score": 120.4}},
            "lstm16": {"straight": {"best_f3": 17.9, "best_score": 40.1}, "turn": {"best_f3": 48.2, "best_score": 99.0}}}
    pool = {"by_model": {
        "FED-LSTM": {"straight": {"n": 2, "completed": 2, "time_s": {"min": 18.79, "median": 20.93},
                                  "mae_x_m": {"median": 0.252}},
                     "turn": {"n": 2, "completed": 0, "time_s": {"min": 60.0, "median": 60.0},
                              "radius_m": {"median": 0.203}}},
        "FED-LSTM-16": {"straight": {"n": 2, "completed": 1, "time_s": {"min": 25.5, "median": 42.75},
                                     "mae_x_m": {"median": 0.31}},
                        "turn": {"n": 2, "completed": 1, "time_s": {"min": 51.0, "median": 55.5},
                                 "radius_m": {"median": 0.11}}}}}
    md = seq_len_comparison(MODELS, leg_metrics=_leg(), gait_metrics=gait, pool_summary=pool)
    # accuracy: EF first, both models' MSE and R^2, and the 16/32 MSE ratio computed here: 0.0026 / 0.0013 = 2.00
    assert _row(md, "| fz_n") == ["fz_n (N^2)", "0.0128", "0.0013", "0.955", "0.0026", "0.940", "2.00"]
    assert _row(md, "| tx_nm")[-1] == "1.50"   # 3.6e-5 / 2.4e-5
    # optimiser: f3 at the 60 s cap is not a time
    assert _row(md, "| straight | 15.3") == ["straight", "15.3", "34.98", "17.9", "40.10"]
    assert _row(md, "| turn | not finished") == ["turn", "not finished (60.0)", "120.40", "48.2", "99.00"]
    # pool: finished counts, best finished time, an all-unfinished task says so
    assert _row(md, "| straight | FED-LSTM (16)") == ["straight", "FED-LSTM (16)", "1/2", "25.5", "42.8",
                                                      "MAE(X) (m) 0.31"]
    assert _row(md, "| turn | FED-LSTM (32)") == ["turn", "FED-LSTM (32)", "0/2", "none finished",
                                                  ">= 60 (unfinished)", "r_T (m) 0.203"]
    assert "Not available" not in md


def test_missing_inputs_are_named_not_invented(tmp_path):
    md = seq_len_comparison(MODELS, leg_metrics={"lstm": _leg()["lstm"]})
    assert _row(md, "| fy_n") == ["fy_n (N^2)", "0.0008", "0.978", "-", "-", "-"]
    assert "no held-out metrics for lstm16" in md and "no optimiser metrics for straight-lstm16" in md
    assert "no pool summary" in md
    # from files as the pipeline leaves them: a missing file is left out
    (tmp_path / "straight-lstm16.metrics.json").write_text(json.dumps({"best_f3": 20.0, "best_score": 50.0}))
    (tmp_path / "m.json").write_text(json.dumps(_leg()))
    got = seq_len_inputs(["lstm", "lstm16"], leg_metrics_paths=[str(tmp_path / "m.json")], gaits_dir=str(tmp_path),
                         pool_summary_path=str(tmp_path / "absent.json"))
    assert got["gait_metrics"] == {"lstm": {}, "lstm16": {"straight": {"best_f3": 20.0, "best_score": 50.0}}}
    assert got["pool_summary"] is None and set(got["leg_metrics"]) == {"ef", "lstm", "lstm16"}
    md = seq_len_comparison(MODELS, **got)
    assert _row(md, "| straight | - | - | 20.0")


def test_tables_in_the_reports_shape():
    from workbench.gait.compare import seq_len_tables

    tables, notes = seq_len_tables(MODELS, leg_metrics=_leg(), gait_metrics={}, pool_summary={"by_model": {}})
    assert [len(t) for t in tables] == [3, 3, 3]
    for caption, head, rows in tables:
        assert caption and all(len(r) == len(head) for r in rows)
    assert tables[0][2][0] == ["fy_n (N^2)", "0.0134", "0.0008", "0.978", "0.0012", "0.967", "1.50"]
    assert len(notes) == 1 and "no pool trials of FED-LSTM-16 (turn)" in notes[0]


def test_no_model_is_a_setting_error_in_one_line():
    with pytest.raises(SettingError) as exc:
        seq_len_comparison([])
    msg = str(exc.value)
    assert isinstance(exc.value, ValueError)          # callers written for the old ValueError keep working
    assert msg.startswith("models: the comparison needs at least one model") and "\n" not in msg
