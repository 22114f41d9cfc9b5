"""reference_fault's rules beyond the basic cases of tests/trials/test_geometry.py: which pair coincides, a
nearly collinear triple among more than four points, and a mirror image (every triple flips) against a fold."""

import numpy as np

from workbench.contract.trials import reference_fault

CORNERS = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 5.0], [0.0, 5.0]])


def _camera(m: np.ndarray, flip: bool = False) -> np.ndarray:
    """Pixel positions of tank points through a plain affine camera (x right, y down), mirrored when asked."""
    px = np.column_stack([300.0 + 120.0 * m[:, 0], 700.0 - 110.0 * m[:, 1] + 8.0 * m[:, 0]])
    if flip:
        px[:, 0] = 1000.0 - px[:, 0]
    return px


def test_the_coinciding_pair_is_named_one_based_in_its_space():
    px = _camera(CORNERS)
    close = px.copy()
    close[3] = close[1] + [0.1, 0.0]  # 0.1 px apart: under 1e-3 of a ~700 px spread
    assert reference_fault(close, CORNERS) == "reference_px points 2 and 4 coincide"
    m = CORNERS.copy()
    m[2] = m[0] + [0.001, 0.0]  # 1 mm apart in a 6.4 m spread
    assert reference_fault(px, m) == "reference_m points 1 and 3 coincide"
    assert reference_fault(px, np.ones((4, 2))) == "reference_m points all coincide"


def test_a_collinear_triple_is_refused_among_four_points_and_passed_over_among_five():
    m4 = np.array([[0.0, 0.0], [2.0, 0.0], [4.0, 0.0], [0.0, 5.0]])  # the first three on the tank's edge
    assert reference_fault(_camera(m4), m4) == "reference points 1, 2, 3 are (nearly) collinear"
    m5 = np.vstack([m4, [[4.0, 5.0]]])  # a fifth point: the other triples fix the plane
    assert reference_fault(_camera(m5), m5) is None
    line = np.column_stack([np.linspace(0, 4, 5), np.linspace(0, 5, 5)])  # all five on one line
    assert reference_fault(_camera(line), line) == "reference points are all (nearly) collinear"


def test_a_mirror_image_is_usable_and_a_fold_is_not():
    assert reference_fault(_camera(CORNERS), CORNERS) is None
    assert reference_fault(_camera(CORNERS, flip=True), CORNERS) is None  # every triple flips: one orientation
    folded = _camera(CORNERS)[[0, 1, 3, 2]]  # two points swapped in one list only
    assert "inconsistent orders" in reference_fault(folded, CORNERS)
