"""Homography from reference points, degenerate references, and the trial frame's handedness."""

import numpy as np
import pytest

from workbench.contract.trials import reference_fault
from workbench.errors import DataError
from workbench.trials.geometry import apply_homography, plane_homography, trial_frame
from workbench.virtual_lab.pool import PoolSettings, TiltedCamera

CORNERS = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 5.0], [0.0, 5.0]])


def test_homography_inverts_the_tilted_camera():
    cam = TiltedCamera.looking_at(PoolSettings())
    px = cam.project(CORNERS)
    h = plane_homography(px, CORNERS)
    rng = np.random.default_rng(0)
    pts = rng.uniform([0, 0], [4, 5], (50, 2))
    assert np.allclose(apply_homography(h, cam.project(pts)), pts, atol=1e-6)
    # more than four points: least squares, same answer on exact points
    extra = np.vstack([CORNERS, [[2.0, 2.5], [1.0, 4.0]]])
    h6 = plane_homography(cam.project(extra), extra)
    assert np.allclose(apply_homography(h6, cam.project(pts)), pts, atol=1e-6)
    assert np.all(np.isnan(apply_homography(h, np.array([[np.nan, np.nan]]))))


@pytest.mark.parametrize("px, fault", [
    ([[0, 0], [100, 0], [200, 0], [0, 100]], "collinear"),
    ([[0, 0], [0, 0], [100, 100], [0, 100]], "coincide"),
    ([[0, 0], [100, 0], [0, 100], [100, 100]], "inconsistent orders"),
    ([[0, 0], [100, 0], [100, 100]], "at least four"),
])
def test_degenerate_references_are_refused(px, fault):
    m = CORNERS[: len(px)] if len(px) < 4 else CORNERS
    assert fault in reference_fault(np.array(px, float), m)
    with pytest.raises(DataError, match="degenerate reference points"):
        plane_homography(np.array(px, float), m)


def test_trial_frame_is_heading_up_right_handed():
    # heading along tank +Y: trial X is tank +X (to the robot's right), trial Y is tank +Y
    f = trial_frame((1.0, 2.0), (0.0, 1.0))
    assert np.allclose(f.to_trial([[2.0, 2.0], [1.0, 3.0]]), [[1.0, 0.0], [0.0, 1.0]])
    # heading along tank +X: its right is tank -Y
    g = trial_frame((0.0, 0.0), (2.0, 0.0))
    assert np.allclose(g.to_trial([[0.0, -1.0]]), [[1.0, 0.0]])
    assert np.allclose(g.to_tank(g.to_trial([[0.3, 0.7]])), [[0.3, 0.7]])
    with pytest.raises(DataError):
        trial_frame((0, 0), (0, 0))
