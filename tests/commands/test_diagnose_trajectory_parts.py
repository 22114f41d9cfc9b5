"""The trajectory-level diagnose command's helpers: model order, metrics file, effect lines."""

import json
from types import SimpleNamespace

from workbench.commands.diagnose import _in_given_order, _print_trajectory_effects, _write_trajectory_metrics


def test_models_in_the_order_given_whatever_order_they_swam():
    swum = {"EF": {"spec": "ef"}, "FED-LSTM": {"spec": "models/lstm"}, "augmented EF": {"spec": "aug.json"}}
    ordered = _in_given_order(["models/lstm", "aug.json", "ef"], swum)
    assert list(ordered) == ["FED-LSTM", "augmented EF", "EF"]
    assert list(_in_given_order(["ef"], swum)) == ["EF"]


def test_metrics_file_has_each_models_errors(tmp_path):
    ordered = {"EF": {"rms_position_m": 1.5, "rms_heading_deg": 80.0, "mean_final_position_m": 2.0, "n_trials": 8,
                      "effects": [{"name": "current"}]},
               "FED-LSTM": {"rms_position_m": 0.4, "n_trials": 7}}
    path = tmp_path / "metrics" / "trajectory.json"
    _write_trajectory_metrics(path, ordered)
    doc = json.loads(path.read_text())
    assert doc == {"trajectory_error": {
        "EF": {"rms_position_m": 1.5, "rms_heading_deg": 80.0, "mean_final_position_m": 2.0, "n_trials": 8},
        "FED-LSTM": {"rms_position_m": 0.4, "rms_heading_deg": None, "mean_final_position_m": None, "n_trials": 7}}}


def test_effect_lines(capsys):
    d = SimpleNamespace(effects=[{"name": "current", "params": {"cx_mps": 0.01, "cy_mps": -0.0123456}}],
                        unexplained=[{"kind": "yaw", "rate_dps": -1.25}, {"kind": "position"}])
    _print_trajectory_effects({"reference": d})
    assert capsys.readouterr().err.splitlines() == ["  reference: effect current: cx_mps=0.01, cy_mps=-0.01235",
                                                    "  reference: unexplained yaw (-1.25 deg/s)",
                                                    "  reference: unexplained position"]
