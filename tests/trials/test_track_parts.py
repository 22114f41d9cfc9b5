"""The tracker's per-frame steps one at a time: predict, speed gate, spacing check, re-acquire, remember."""

import cv2
import numpy as np
import pytest

from workbench.trials.detect import Blob
from workbench.trials.track import MarkerTracker
from workbench.virtual_lab.pool import MARKER_BGR

H = np.diag([0.01, 0.01, 1.0])  # 1 px = 1 cm on the water plane


def blob(u, v):
    return Blob(u=u, v=v, area_px=80.0, saturation=200.0)


def seen(tracker, t, head, tail):
    """The tracker has seen the markers at ``head``/``tail`` (px) at time ``t``."""
    tracker._remember([np.array(head, float), np.array(tail, float)], t)


def test_remember_smooths_velocity_and_keeps_spacings():
    tr = MarkerTracker(H, "red", "blue")
    seen(tr, 0.0, (100, 100), (80, 100))
    seen(tr, 0.1, (110, 100), (90, 100))          # 100 px/s along u
    assert tr.vel_px[0] == pytest.approx([50.0, 0.0])   # half the old (0) and half the new
    seen(tr, 0.2, (120, 100), (100, 100))
    assert tr.vel_px[0] == pytest.approx([75.0, 0.0])
    assert list(tr.spacings) == pytest.approx([0.2, 0.2, 0.2])
    tr._remember([np.array([130.0, 100.0]), None], 0.3)  # the tail hidden: no spacing recorded
    assert len(tr.spacings) == 3 and tr.last_t == [0.3, 0.2]


def test_predict_extrapolates_at_most_half_a_second():
    tr = MarkerTracker(H, "red", "blue")
    seen(tr, 0.0, (100, 100), (80, 100))
    seen(tr, 0.1, (110, 100), (90, 100))          # velocity 50 px/s
    assert tr._predict(0.3)[0] == pytest.approx([120.0, 100.0])
    assert tr._predict(5.0)[0] == pytest.approx([135.0, 100.0])


def test_speed_gate_takes_the_nearest_blob_within_reach():
    tr = MarkerTracker(H, "red", "blue")
    seen(tr, 0.0, (100, 100), (80, 100))
    preds = tr._predict(0.1)
    # within 0.1 s at 1 m/s + 3 cm a marker moves at most 13 px; the head's near blob is 20 px away
    found = tr._gated({0: [blob(121, 100), blob(200, 100)], 1: [blob(85, 100), blob(82, 100)]}, preds, 0.1)
    assert found[0] is None
    assert found[1] == pytest.approx([82.0, 100.0])


def test_spacing_check_drops_the_marker_that_strays_from_its_prediction():
    tr = MarkerTracker(H, "red", "blue")
    for k in range(4):
        seen(tr, 0.1 * k, (100 + k, 100), (80 + k, 100))
    preds = tr._predict(0.4)
    found = [np.array([104.0, 100.0]), np.array([84.0, 150.0])]   # tail 50 cm off: spacing 0.54 m
    tr._check_spacing(found, preds, 0.4)
    assert found[0] is not None and found[1] is None
    # alone, the head must still sit near its hidden partner's last place
    alone = [np.array([104.0, 160.0]), None]
    tr._check_spacing(alone, preds, 0.4)
    assert alone == [None, None]
    near = [np.array([104.5, 100.0]), None]
    tr._check_spacing(near, preds, 0.4)
    assert near[0] is not None


def test_reacquire_locks_only_onto_a_reachable_pair():
    img = np.full((200, 300, 3), (110, 115, 100), np.uint8)
    cv2.circle(img, (150, 100), 5, MARKER_BGR["red"], -1)
    cv2.circle(img, (130, 100), 5, MARKER_BGR["blue"], -1)
    fresh = MarkerTracker(H, "red", "blue")
    found = fresh._reacquire(img, 1.0, [None, None])
    assert fresh.locked and fresh.next_search_t == pytest.approx(1.0 + fresh.p.search_every_s)
    assert found[0] == pytest.approx([150, 100], abs=0.3) and found[1] == pytest.approx([130, 100], abs=0.3)
    far = MarkerTracker(H, "red", "blue")
    seen(far, 0.95, (20, 20), (20, 40))          # 1.4 m away 0.05 s ago: out of reach
    assert far._reacquire(img, 1.0, [None, None]) == [None, None] and not far.locked
