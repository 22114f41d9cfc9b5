"""The pool verdict's parts: one model's pool statistics, and the reasons read from the predictions."""

import json

import pytest

from workbench.report.verdict import _pool_stats, _prediction_reasons, _task_verdict


def model(label, achieved, predicted, completed=1, n=2, mismatch=None):
    return {"label": label, "n": n, "achieved": achieved, "completed": completed, "predicted": predicted,
            "mismatch": mismatch}


def test_pool_stats_means_and_predictions(tmp_path):
    (tmp_path / "gaits").mkdir()
    sols = [{"rank": 1, "objectives": {"f3": 20.0}}, {"rank": 2, "objectives": {"f3": 30.0}}]
    settings = {"task": {"cap_s": 60.0, "finish_distance_m": 1.5}}
    (tmp_path / "gaits/straight-lstm.json").write_text(json.dumps({"solutions": sols, "settings": settings}))
    rows = [{"task": "straight", "model": "FED-LSTM", "solution": "1", "time_s": "25.0", "completed": "true"},
            {"task": "straight", "model": "FED-LSTM", "solution": "2", "time_s": "60.0", "completed": "false"},
            {"task": "turn", "model": "FED-LSTM", "solution": "1", "time_s": "9.0", "completed": "true"}]
    st = _pool_stats(tmp_path, "straight", "lstm", "FED-LSTM", rows)
    assert st["n"] == 2 and st["completed"] == 1
    assert st["achieved"] == pytest.approx(42.5) and st["predicted"] == pytest.approx(25.0)
    assert st["mismatch"] == "finish_distance_m 1.5 instead of 2"
    # a trial whose gait is not in the file: no mean prediction
    rows[1]["solution"] = "9"
    assert _pool_stats(tmp_path, "straight", "lstm", "FED-LSTM", rows)["predicted"] is None
    assert _pool_stats(tmp_path, "straight", "ef", "EF", rows) is None


def test_reasons_for_a_loss():
    ls, ef = model("FED-LSTM", 40.0, 30.0), model("EF", 35.0, 34.0)
    gap = {"lstm": 10.0, "ef": 1.0}
    (why,) = _prediction_reasons(ls, ef, gap, neither=False, better=False)
    assert why.startswith("the FED-LSTM is 10.0 s optimistic")
    slow = model("FED-LSTM", 40.0, 36.0)
    reasons = _prediction_reasons(slow, ef, {"lstm": 4.0, "ef": 1.0}, neither=False, better=False)
    assert len(reasons) == 2 and reasons[0].startswith("the FED-LSTM predicted its own gaits no faster")
    assert reasons[1].startswith("the FED-LSTM is 4.0 s optimistic")
    assert _prediction_reasons(ls, ef, gap, neither=False, better=True) == []


def test_reasons_when_neither_finished():
    ls, ef = model("FED-LSTM", 60.0, 45.0, completed=0), model("EF", 60.0, 70.0, completed=0)
    (why,) = _prediction_reasons(ls, ef, {"lstm": 15.0, "ef": -10.0}, neither=True, better=False)
    assert "FED-LSTM predicted its gaits to finish in 45.0 s" in why


def test_task_verdict_text():
    text = _task_verdict("straight", model("FED-LSTM", 20.0, 19.0, completed=2), model("EF", 30.0, 29.0))
    assert text.startswith("**straight: FED-LSTM gaits beat EF gaits on the virtual truth.**")
    assert "(pool minus prediction: +1.0 s and +1.0 s)" in text and "Why" not in text and "Caveat" not in text
    lost = _task_verdict("turn", model("FED-LSTM", 60.0, None, completed=0), model("EF", 60.0, None, completed=0))
    assert "neither model's gaits finished" in lost and "mean yaw torque cancels" in lost
    other = _task_verdict("straight", model("FED-LSTM", 20.0, 19.0, mismatch="cap_s 20 instead of 60"),
                          model("EF", 30.0, 29.0))
    assert "Caveat: the FED-LSTM gaits were optimised for another task" in other and "Predicted by" not in other
