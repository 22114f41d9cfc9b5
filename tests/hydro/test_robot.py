"""Robot constants: Rodrigues rotation, leg frames and mirroring, drag laws, loading from YAML and drag.json."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from workbench.errors import ContractError
from workbench.hydro.robot import (
    LEG_NAMES,
    PAPER_FORWARD_DRAG,
    DragLaw,
    RobotSettings,
    load_robot,
    robot_from_dict,
    rodrigues,
)
from workbench.project import project_root


@pytest.mark.parametrize("axis,angle", [([0, 1, 0], 0.5), ([1, 0, 2], -1.2), ([0.3, -0.4, 0.8], 2.9)])
def test_rodrigues_matches_scipy(axis, angle):
    r = rodrigues(axis, angle)
    ref = Rotation.from_rotvec(np.asarray(axis, float) / np.linalg.norm(axis) * angle).as_matrix()
    np.testing.assert_allclose(r, ref, atol=1e-14)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-14)


def test_haa_abduction_tilts_each_leg_outboard_and_up():
    robot = RobotSettings()
    forces, torques = robot.leg_rotations()
    down = np.array([0.0, 0.0, -1.0])
    lf, rf, lh, rh = (forces[i] @ down for i in range(4))
    # front legs rotated 30 deg: their "down" leans outboard (left legs to -x, right legs to +x)
    np.testing.assert_allclose(lf, [-0.5, 0.0, -np.sqrt(3) / 2], atol=1e-12)
    np.testing.assert_allclose(rf, [0.5, 0.0, -np.sqrt(3) / 2], atol=1e-12)
    np.testing.assert_allclose(lh, down, atol=1e-12)
    np.testing.assert_allclose(rh, down, atol=1e-12)
    # forward stays forward for a fore-aft HAA axis
    np.testing.assert_allclose(robot.leg_forward_axes(), np.tile([0.0, 1.0, 0.0], (4, 1)), atol=1e-12)
    # torques are axial vectors: a mirrored leg's torque map is minus its force map
    for i, mirrored in enumerate(robot.mirrored):
        np.testing.assert_allclose(torques[i], -forces[i] if mirrored else forces[i])
        assert np.isclose(np.linalg.det(forces[i]), -1.0 if mirrored else 1.0)


def test_right_legs_are_the_mirror_images_of_the_left():
    robot = RobotSettings()
    forces, _ = robot.leg_rotations()
    m = np.diag([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(forces[1], m @ forces[0])
    np.testing.assert_allclose(forces[3], m @ forces[2])
    hips = robot.hip_positions_m()
    np.testing.assert_allclose(hips[1], m @ hips[0], atol=1e-15)
    np.testing.assert_allclose(hips[3], m @ hips[2], atol=1e-15)
    # hind left hip: HAA joint (-0.04, -0.10, 0) plus the 0.03 m abduction offset outboard
    np.testing.assert_allclose(hips[2], [-0.07, -0.10, 0.0], atol=1e-15)


def test_drag_law_below_range_goes_linearly_to_zero():
    law = DragLaw(PAPER_FORWARD_DRAG, (0.10, 0.35), "linear_to_zero")
    at_v0 = 9.997 * 0.01 - 0.0132 + 0.334
    np.testing.assert_allclose(law.magnitude([0.0, 0.05, 0.10, 0.2]),
                               [0.0, at_v0 / 2, at_v0, 9.997 * 0.04 - 0.132 * 0.2 + 0.334])
    np.testing.assert_allclose(law.force([-0.2, 0.0, 0.2]), [law.magnitude(0.2), 0.0, -law.magnitude(0.2)])
    fitted = DragLaw(PAPER_FORWARD_DRAG, (0.10, 0.35), "as_fitted")
    np.testing.assert_allclose(fitted.magnitude(1e-9), 0.334, rtol=1e-6)  # the paper's drag at rest
    with pytest.raises(ValueError):
        DragLaw(PAPER_FORWARD_DRAG, below_range="nonsense")


def test_drag_law_drop_intercept_is_the_polynomial_without_c0():
    law = DragLaw(PAPER_FORWARD_DRAG, (0.10, 0.35))
    assert law.below_range == "drop_intercept"
    v = np.array([0.0, 0.005, 0.05, 0.2])
    np.testing.assert_allclose(law.magnitude(v), np.maximum(9.997 * v**2 - 0.132 * v, 0.0))
    np.testing.assert_allclose(law.force([-0.2, 0.2]), [law.magnitude(0.2), -law.magnitude(0.2)])


def test_repository_robot_yaml_matches_the_documented_defaults():
    loaded = load_robot(project_root() / "pipelines/robot.yaml")
    assert loaded == RobotSettings()
    assert loaded.drag_source == "paper"


def test_drag_json_replaces_the_body_drag(tmp_path):
    doc = {"forward": {"coefficients": [8.0, 0.5, 0.01], "stderr": [1, 1, 1], "r2": 0.99,
                       "speed_range_mps": [0.05, 0.3]},
           "lateral": {"coefficients": [12.0, 1.0, 0.0], "stderr": [1, 1, 1], "r2": 0.98}}
    path = tmp_path / "drag.json"
    path.write_text(json.dumps(doc))
    robot = load_robot(project_root() / "pipelines/robot.yaml", drag_json=path)
    assert robot.forward_drag.coefficients == (8.0, 0.5, 0.01)
    assert robot.forward_drag.speed_range_mps == (0.05, 0.3)
    assert robot.lateral_drag.speed_range_mps == (0.10, 0.35)  # not in the file: the default range
    assert robot.drag_source == str(path)
    path.write_text(json.dumps({"forward": doc["forward"]}))
    with pytest.raises(ContractError, match="lateral.coefficients"):
        load_robot(project_root() / "pipelines/robot.yaml", drag_json=path)
    with pytest.raises(ContractError, match="not found"):
        load_robot(project_root() / "pipelines/robot.yaml", drag_json=tmp_path / "missing.json")


def test_bad_robot_parameters_are_refused_with_the_file_named():
    from workbench.errors import ParamsError

    with pytest.raises(ParamsError, match=r"^robot\.yaml, legs\.mirrored\[0\]: must be one of 'LF', 'RF', 'LH', 'RH', got 'RX'"):
        robot_from_dict({"legs": {"mirrored": ["RX"]}}, path="robot.yaml")
    with pytest.raises(ParamsError, match=r"robot\.yaml, legs\.haa_angle_deg: lacks legs \['RF', 'LH', 'RH'\]"):
        robot_from_dict({"legs": {"haa_angle_deg": {"LF": 30}}}, path="robot.yaml")
    with pytest.raises(ParamsError, match=r"robot\.yaml: mass_kg and yaw_inertia_kgm2 must be positive"):
        robot_from_dict({"robot": {"mass_kg": -1}}, path="robot.yaml")
    # a misspelt key was silently ignored before issue 17: now file, key path and the allowed keys
    with pytest.raises(ParamsError, match=r"robot\.yaml, legs\.haa_angel_deg: unknown setting 'haa_angel_deg' "
                                          r"\(did you mean 'haa_angle_deg'\? allowed: haa_position_m, hip_offset_m"):
        robot_from_dict({"legs": {"haa_angel_deg": [0, 0, 0, 0]}}, path="robot.yaml")
    with pytest.raises(ParamsError, match=r"body_drag\.below_range: must be one of .* got 'linear'"):
        robot_from_dict({"body_drag": {"below_range": "linear"}}, path="robot.yaml")
    with pytest.raises(ParamsError, match=r"legs\.haa_angle_deg\.XX: unknown leg 'XX'"):
        robot_from_dict({"legs": {"haa_angle_deg": {"LF": 1, "RF": 1, "LH": 1, "RH": 1, "XX": 2}}}, path="robot.yaml")
    assert robot_from_dict({"legs": {"haa_angle_deg": [0, 0, 0, 0]}}).haa_angle_deg == (0, 0, 0, 0)
    assert len(LEG_NAMES) == 4


def test_the_robot_files_simulation_section_is_checked_with_the_file_named(tmp_path):
    import yaml

    from workbench.commands.simulate import robot_simulation_settings
    from workbench.errors import ParamsError

    doc = yaml.safe_load((project_root() / "pipelines/robot.yaml").read_text())
    assert robot_simulation_settings(str(project_root() / "pipelines/robot.yaml")) == doc["simulation"]
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump({**doc, "simulation": {"metod": "picard"}}))
    with pytest.raises(ParamsError, match=rf"^{path}, simulation\.metod: unknown setting 'metod' \(did you mean "
                                          r"'method'\? allowed: duration_s, dt_s"):
        robot_simulation_settings(str(path))
    path.write_text(yaml.safe_dump({**doc, "simulation": {"method": "picardd", "max_iter": 3}}))
    with pytest.raises(ParamsError, match=r"simulation\.method: must be one of 'windowed', 'picard', got 'picardd'"):
        robot_simulation_settings(str(path))
