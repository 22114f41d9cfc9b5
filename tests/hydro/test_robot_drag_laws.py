"""Where the robot's body drag laws come from: the paper, the parameter file, or a fitted drag.json."""

import json

from workbench.hydro.robot import (
    PAPER_FORWARD_DRAG,
    PAPER_LATERAL_DRAG,
    BodyDragSettings,
    DragHeadingSettings,
    _drag_laws,
    robot_from_dict,
)


def test_paper_coefficients_by_default():
    laws, source = _drag_laws(BodyDragSettings(below_range="as_fitted"), None, "robot.yaml")
    assert source == "paper"
    assert laws["forward"].coefficients == PAPER_FORWARD_DRAG and laws["lateral"].coefficients == PAPER_LATERAL_DRAG
    assert laws["forward"].below_range == "as_fitted"


def test_own_coefficients_name_the_parameter_file():
    drag = BodyDragSettings(lateral=DragHeadingSettings(coefficients=(20.0, 1.0, 0.1), speed_range_mps=(0.05, 0.3)))
    laws, source = _drag_laws(drag, None, "pipelines/robot.yaml")
    assert source == "pipelines/robot.yaml"
    assert laws["forward"].coefficients == PAPER_FORWARD_DRAG
    assert laws["lateral"].coefficients == (20.0, 1.0, 0.1) and laws["lateral"].speed_range_mps == (0.05, 0.3)
    assert _drag_laws(drag, None, None)[1] == "robot parameters"


def test_a_drag_json_replaces_both_laws(tmp_path):
    path = tmp_path / "drag.json"
    path.write_text(json.dumps({"forward": {"coefficients": [1.0, 2.0, 3.0], "speed_range_mps": [0.1, 0.4]},
                                "lateral": {"coefficients": [4.0, 5.0, 6.0]}}))
    drag = BodyDragSettings(forward=DragHeadingSettings(coefficients=(20.0, 1.0, 0.1)))
    laws, source = _drag_laws(drag, path, "robot.yaml")
    assert source == str(path)
    assert laws["forward"].coefficients == (1.0, 2.0, 3.0) and laws["forward"].speed_range_mps == (0.1, 0.4)
    assert laws["lateral"].coefficients == (4.0, 5.0, 6.0)
    # the argument wins over the file's body_drag.drag_json
    robot = robot_from_dict({"body_drag": {"drag_json": str(tmp_path / "not-read.json")}}, drag_json=path)
    assert robot.drag_source == str(path) and robot.lateral_drag.coefficients == (4.0, 5.0, 6.0)
