"""Outlier rejection, gap filling and smoothing of the marker tracks."""

import numpy as np
import pytest

from workbench.trials.clean import clean_pose, fill_gaps, hampel_mask, smooth_segments, start_heading
from workbench.trials.params import ScoringSettings


def test_hampel_flags_a_spike_only():
    v = np.sin(np.linspace(0, 3, 100))
    v[40] += 0.5
    bad = hampel_mask(v, 15, 4.0, 0.01)
    assert bad[40] and bad.sum() == 1


def test_fill_short_gaps_only():
    t = np.arange(100) / 10.0
    v = t**2
    v[20:25] = np.nan   # 0.6 s between neighbours: filled
    v[50:80] = np.nan   # 3.1 s: left as a gap
    out, filled = fill_gaps(t, v, 1.5)
    assert filled[20:25].all() and not filled[50:80].any()
    assert np.allclose(out[20:25], t[20:25] ** 2, atol=0.05)
    assert np.isnan(out[50:80]).all()


def test_smoothing_keeps_a_quadratic_and_reduces_noise():
    t = np.linspace(0, 10, 301)
    truth = 0.05 * t**2
    noisy = truth + np.random.default_rng(0).normal(0, 0.01, t.size)
    noisy[100:110] = np.nan
    sm = smooth_segments(noisy, 15, 2)
    ok = np.isfinite(sm)
    assert np.isnan(sm[100:110]).all()
    assert np.std(sm[ok] - truth[ok]) < 0.6 * np.std(noisy[ok] - truth[ok])


def _pose_from(t, x, y, heading, h=None, spacing=0.2):
    """Pixel tracks of two markers for a pose series under an identity homography (1 px = 1 m)."""
    fwd = np.column_stack([np.cos(heading), np.sin(heading)])
    centre = np.column_stack([x, y])
    return centre + spacing / 2 * fwd, centre - spacing / 2 * fwd


def test_clean_pose_rejects_a_wrong_marker_and_fills_an_occlusion():
    t = np.arange(0, 10, 1 / 15)
    heading = 0.2 * t
    head, tail = _pose_from(t, 0.1 * t, np.zeros_like(t), heading)
    head[30] += [0.5, 0.5]            # a false detection
    head[60:70] = np.nan              # an occlusion of 0.7 s
    tail[60:70] = np.nan
    pose = clean_pose(t, head, tail, np.eye(3), ScoringSettings())
    assert not pose.detected[30]
    assert pose.filled[60:70].all()
    assert np.allclose(pose.x_m, 0.1 * t, atol=2e-3)
    assert np.allclose(pose.heading_rad, heading, atol=2e-3)
    assert start_heading(pose, 3.0, 1.0, 2.0) == pytest.approx(0.6, abs=1e-3)
