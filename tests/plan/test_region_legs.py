"""The operating region swum with each gait file's own legs, EF where that model is not available."""

from __future__ import annotations

import json

import numpy as np

from workbench.commands.plan_campaign import own_legs, read_gait_files
from workbench.hydro.robot import load_robot
from workbench.plan.region import operating_region

GAIT = {"rank": 1, "params": {"theta_h_min_deg": -40.0, "theta_k_max_deg": -70.0, "frequency_hz": 0.6,
                              "alpha_rad": [0.0, 1.5, 3.0, 4.5]}}


def _file(tmp_path, name, spec):
    p = tmp_path / f"{name}.json"
    p.write_text(json.dumps({"model_spec": spec, "solutions": [GAIT]}))
    return p


class StrongLegs:
    """EF legs whose wrench is multiplied by ``k`` (the flow a leg sees must change with its forces)."""

    def __init__(self, k):
        from workbench.hydro.ef import EmpiricalFormula

        self.ef, self.k, self.name = EmpiricalFormula(), k, f"ef x{k}"

    def wrench(self, motion):
        return self.k * np.asarray(self.ef.wrench(motion))


def test_own_legs_fall_back_to_ef_with_a_note_and_other_legs_change_the_flow(tmp_path):
    kw = dict(duration_s=6.0, points_per_cycle=8)
    robot = load_robot("pipelines/robot.yaml")
    missing = _file(tmp_path, "a", str(tmp_path / "no-such-model"))
    both = read_gait_files([missing, _file(tmp_path, "b", "ef")])
    ef_file = both[1:]
    own = operating_region(both, robot, legs=own_legs(), **kw)
    plain = operating_region(both, robot, **kw)
    assert "EF (fallback" in own.leg_models[0] and "no-such-model" in own.leg_models[0]
    assert "fallback" not in own.leg_models[1]
    # both files swum with EF legs: the same states as the EF region
    assert np.allclose(own.states(), plain.states())
    # a stronger leg model in the swim: the legs see a faster flow (the robot swims faster)
    strong = operating_region(ef_file, robot, legs=lambda path, doc, gaits: (StrongLegs(2.0), "strong"), **kw)
    weak = operating_region(ef_file, robot, **kw)
    assert strong.leg_models == ("b.json: strong",)
    assert strong.states()[:, 0].mean() > 1.1 * weak.states()[:, 0].mean()
