"""Marker detection by colour name: every contract colour, in dim and bright light, glare rejected."""

import cv2
import numpy as np
import pytest

from workbench.contract.trials import MARKER_COLOURS
from workbench.trials.detect import ColourGate, find_blobs
from workbench.trials.track import MarkerTracker
from workbench.virtual_lab.pool import MARKER_BGR


def scene(colour, centre, gain=1.0, glare=False):
    img = np.full((120, 160, 3), (110, 115, 100), np.uint8)  # pale, grey-green water
    cv2.circle(img, (80, 60), 25, (40, 40, 44), -1)         # dark robot body
    c = (int(round(centre[0] * 16)), int(round(centre[1] * 16)))
    cv2.circle(img, c, 6 * 16, MARKER_BGR[colour], -1, cv2.LINE_AA, 4)
    if glare:
        cv2.ellipse(img, (40, 30), (20, 8), 0, 0, 360, (250, 250, 250), -1)
    return cv2.convertScaleAbs(img, alpha=gain)


@pytest.mark.parametrize("colour", MARKER_COLOURS)
@pytest.mark.parametrize("gain", [0.55, 1.0, 1.3])
def test_each_colour_found_at_sub_pixel_accuracy(colour, gain):
    centre = (77.3, 58.6)
    hsv = cv2.cvtColor(scene(colour, centre, gain, glare=True), cv2.COLOR_BGR2HSV)
    blobs = find_blobs(hsv, ColourGate(colour))
    assert len(blobs) == 1
    assert abs(blobs[0].u - centre[0]) < 0.15 and abs(blobs[0].v - centre[1]) < 0.15
    # and no other colour claims it
    others = [c for c in MARKER_COLOURS if c != colour]
    assert all(not find_blobs(hsv, ColourGate(o)) for o in others)


def test_tracker_follows_and_ignores_a_far_decoy():
    h = np.diag([0.01, 0.01, 1.0])  # 1 px = 1 cm on the water plane
    tracker = MarkerTracker(h, "red", "blue")
    for k in range(10):
        img = np.full((200, 300, 3), (110, 115, 100), np.uint8)
        x = 100 + 2 * k
        cv2.circle(img, (x, 100), 5, MARKER_BGR["red"], -1)
        cv2.circle(img, (x - 20, 100), 5, MARKER_BGR["blue"], -1)
        if k >= 5:  # a red decoy appears 1.2 m away
            cv2.circle(img, (x + 120, 160), 5, MARKER_BGR["red"], -1)
        head, tail = tracker.update(img, k / 15)
        assert head[0] == pytest.approx(x, abs=0.3) and head[1] == pytest.approx(100, abs=0.3)
        assert tail[0] == pytest.approx(x - 20, abs=0.3)
    assert tracker.n_searches == 1
