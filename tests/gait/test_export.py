"""The gait file (data contract section 5) and the controller file."""

import math

import numpy as np
import pytest

from workbench.gait.export import best_table, controller_document, gait_document, joint_functions, model_label
from workbench.gait.objectives import TaskSpec
from workbench.hydro.motion import JointSinusoid
from workbench.hydro.simulator import GaitBatch

SPEC = TaskSpec("straight", cap_s=20.0, finish_distance_m=1.0)


def _batch():
    return GaitBatch.from_arrays([-30.0, 5.0], [-70.0, -25.0], [0.5, 0.33], [[0.1, 3.0, 4.0, 6.2], [1, 2, 3, 4]])


def check_contract_gait_file(doc, task, model):
    """Data contract section 5, exactly: the shape other programs rely on."""
    assert doc["task"] == task and doc["model"] == model
    sols = doc["solutions"]
    assert isinstance(sols, list) and sols
    assert [s["rank"] for s in sols] == list(range(1, len(sols) + 1))
    scores = [s["score"] for s in sols]
    assert scores == sorted(scores)
    for s in sols:
        assert set(s) >= {"rank", "params", "objectives", "score"}
        p = s["params"]
        assert set(p) == {"theta_h_min_deg", "theta_k_max_deg", "frequency_hz", "alpha_rad"}
        assert isinstance(p["theta_h_min_deg"], float) and isinstance(p["theta_k_max_deg"], float)
        assert isinstance(p["frequency_hz"], float)
        assert isinstance(p["alpha_rad"], list) and len(p["alpha_rad"]) == 4
        assert set(s["objectives"]) == {"f1", "f2", "f3"}
        assert all(isinstance(v, float) and math.isfinite(v) for v in s["objectives"].values())


def test_gait_document_follows_the_contract():
    f = np.array([[-0.2, 0.01, 9.0], [-0.1, 0.2, 12.0]])
    s = f @ np.array([1.0, 4.0, 2.0])
    doc = gait_document(SPEC, "ef", _batch(), f, s, extra={"seed": 3})
    check_contract_gait_file(doc, "straight", "ef")
    assert doc["solutions"][1]["params"]["alpha_rad"] == [1.0, 2.0, 3.0, 4.0]
    assert doc["seed"] == 3 and doc["weights"] == [1.0, 4.0, 2.0]
    rows = best_table(SPEC, _batch(), f, s)
    assert rows[0]["alpha_rf_rad"] == 3.0 and rows[1]["score"] == pytest.approx(s[1])


def test_controller_functions_reproduce_equation_3():
    g = _batch()
    t = np.linspace(0, 7, 300)
    for i in range(len(g)):
        legs = joint_functions(g, i)
        for j, leg in enumerate(("LF", "RF", "LH", "RH")):
            js = JointSinusoid(float(g.theta_h_min_deg[i, j]), g.theta_h_max_deg, g.theta_k_min_deg,
                               float(g.theta_k_max_deg[i, j]), float(g.frequency_hz[i]), g.phi_rad,
                               float(g.alpha_rad[i, j]))
            th, tk = js.evaluate(t)[:2]
            for joint, want in (("hfe", th), ("kfe", tk)):
                c = legs[leg][joint]
                assert c["amplitude_deg"] >= 0 and 0 <= c["phase_rad"] < 2 * math.pi
                got = c["offset_deg"] + c["amplitude_deg"] * np.sin(2 * np.pi * g.frequency_hz[i] * t + c["phase_rad"])
                np.testing.assert_allclose(got, want, atol=1e-9)


def test_controller_document_samples_one_cycle():
    g = _batch()
    doc = controller_document(SPEC, "lstm", g, np.array([1.0, 2.0]), sample_rate_hz=65.0, haa_deg=(30, 30, 0, 0))
    assert doc["schema"] == "workbench/gait-controller@1" and doc["legs"] == ["LF", "RF", "LH", "RH"]
    assert doc["haa_deg"]["LF"] == 30.0
    cyc = doc["gaits"][1]["cycle"]
    assert len(cyc["time_s"]) == round(65 / 0.33)
    th = JointSinusoid(5.0, -100.0, 80.0, -25.0, 0.33, math.pi / 3, 2.0).evaluate(np.asarray(cyc["time_s"]))[0]
    np.testing.assert_allclose(cyc["RF"]["hfe_deg"], th, atol=1e-4)


def test_model_labels_are_file_safe():
    assert model_label("ef") == "ef" and model_label("lstm") == "lstm"
    assert model_label("models:/fed-lstm@tuned") == "fed-lstm-tuned"
    assert model_label("models:/fed-lstm/3") == "fed-lstm-3"
