"""The comparison's three tables built one at a time (inputs planted here)."""

from workbench.gait.compare import _accuracy_table, _optimiser_table, _pool_cells, _pool_table

TITLES = {"a": "A", "b": "B"}


def test_accuracy_ratio_and_a_zero_mse():
    leg = {"ef": {"mse": {"fy_n": 0.5}}, "a": {"mse": {"fy_n": 0.02, "fz_n": 0.0}, "r2": {"fy_n": 0.9}},
           "b": {"mse": {"fy_n": 0.03, "fz_n": 0.1}}}
    missing = []
    caption, head, rows = _accuracy_table(["a", "b"], TITLES, leg, ("fy_n", "fz_n"), "ef", missing)
    assert head == ["channel", "EF MSE", "A MSE", "A R^2", "B MSE", "B R^2", "MSE B / A"]
    assert rows[0] == ["fy_n (N^2)", "0.5", "0.02", "0.900", "0.03", "-", "1.50"]
    assert rows[1][-1] == "-"           # a zero MSE gives no ratio
    assert missing == []
    _accuracy_table(["a", "c"], {**TITLES, "c": "C"}, leg, ("fy_n",), "zz", missing)
    assert missing == ["no held-out metrics for c"]


def test_optimiser_marks_a_time_at_the_cap_unfinished():
    gm = {"a": {"straight": {"best_f3": 12.34, "best_score": 3.0}, "turn": {"best_f3": 60.0}}}
    missing = []
    _, head, rows = _optimiser_table(["a", "b"], TITLES, gm, 60.0, missing)
    assert rows == [["straight", "12.3", "3.00", "-", "-"], ["turn", "not finished (60.0)", "-", "-", "-"]]
    assert missing == ["no optimiser metrics for straight-b", "no optimiser metrics for turn-b"]


def test_pool_cells_never_show_an_unfinished_time():
    st = {"n": 4, "completed": 2, "time_s": {"min": 21.0, "median": 61.0}, "radius_m": {"median": 0.25}}
    assert _pool_cells("turn", st, 60.0) == ["2/4", "21.0", ">= 60 (unfinished)", "r_T (m) 0.25"]
    none = {"n": 3, "completed": 0, "time_s": {"min": 30.0}}
    assert _pool_cells("straight", none, 60.0) == ["0/3", "none finished", "-", "MAE(X) (m) -"]


def test_pool_table_names_what_it_lacks():
    missing = []
    summary = {"by_model": {"A-label": {"straight": {"n": 1, "completed": 1, "time_s": {"min": 9.0, "median": 9.0}}}}}
    _, _, rows = _pool_table(["a"], TITLES, summary, {"a": "A-label"}, 60.0, missing)
    assert rows == [["straight", "A", "1/1", "9.0", "9.0", "MAE(X) (m) -"], ["turn", "A", "-", "-", "-", "-"]]
    assert missing == ["no pool trials of A-label (turn)"]
    missing.clear()
    _pool_table(["a"], TITLES, None, {"a": "A-label"}, 60.0, missing)
    assert missing == ["no pool summary"]
