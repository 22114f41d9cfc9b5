"""The optimiser's tasks are the trials' protocol in the demo, its per_side_range variant and the paper profile.

Issue 14, done when: "the demo and the paper-scale profile use the trials' protocol". The scorer's
constants (data contract section 2: 2 m and 360 deg within 60 s) are the reference; every pipeline
parameter file the optimise stages read, and the paper profile applied to them, must give the same
tasks, and the profile may change study sizes only.
"""

import math
from pathlib import Path

import yaml

from workbench.gait.config import config_from_dict, load_config
from workbench.params import read_section
from workbench.trials.scoring import CAP_S, STRAIGHT_DISTANCE_M, TURN_RAD

REPO = Path(__file__).resolve().parents[2]


def _protocol(cfg, where):
    straight, turn = cfg.task("straight").spec, cfg.task("turn").spec
    assert straight.cap_s == CAP_S and turn.cap_s == CAP_S, where
    assert straight.finish_distance_m == STRAIGHT_DISTANCE_M, where
    assert math.isclose(math.radians(turn.target_yaw_deg), TURN_RAD), where
    assert straight.target_yaw_deg == 0.0 and turn.turn_direction == "either", where  # trials count either way


def test_every_optimise_stage_reads_the_trials_protocol():
    stages = yaml.safe_load((REPO / "dvc.yaml").read_text())["stages"]
    files = set()
    for st in stages.values():
        body = st.get("do", st)
        cmd = " ".join(str(body["cmd"]).split())
        if cmd.startswith("workbench optimize"):
            files.add(cmd.split("--params ")[1].split()[0] if "--params " in cmd else "pipelines/gait.yaml")
    assert {"pipelines/gait.yaml", "pipelines/gait_sides.yaml"} <= files, files
    for f in sorted(files):
        _protocol(load_config(REPO / f), f)


def test_the_paper_profile_changes_study_sizes_not_the_tasks():
    profile = yaml.safe_load((REPO / "pipelines/profiles/paper.yaml").read_text())
    gait_keys = {k.partition(":")[2]: v for k, v in profile["set"].items() if k.startswith("pipelines/gait")}
    assert gait_keys and not any(k.startswith("optimize.tasks") for k in gait_keys), gait_keys
    assert not any(k.partition(":")[2].startswith("scoring") for k in profile["set"])
    # applied to the demo's file (and so to the variant that extends it), the tasks are still the protocol
    raw = read_section(REPO / "pipelines/gait.yaml", "optimize")[0]
    for dotted, value in gait_keys.items():
        node = raw
        *path, last = dotted.split(".")[1:]
        for part in path:
            node = node[part]
        assert last in node, dotted
        node[last] = value
    cfg = config_from_dict(raw, "pipelines/gait.yaml (paper profile)")
    assert cfg.nsga2.pop_size == 64 and cfg.nsga2.n_gen == 50
    _protocol(cfg, "paper profile")
