"""Pixels to tank metres (the water plane's homography) and tank metres to a trial's own frame.

The tank frame is the contract's: world X along the width, world Y along the length, seen from
above with X x Y pointing up (right-handed). A trial's frame has its origin at the robot's
position at ``start_s``, +Y along its heading then, +X to its right.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workbench.contract.trials import reference_fault
from workbench.errors import DataError


def plane_homography(reference_px: np.ndarray, reference_m: np.ndarray) -> np.ndarray:
    """The 3x3 homography mapping pixel ``(u, v)`` to tank ``(x, y)`` metres on the water plane.

    Four points give the exact transform (``cv2.getPerspectiveTransform``); more give the least-
    squares fit (``cv2.findHomography``, no RANSAC: reference points are surveyed, not matched).
    Raises :class:`DataError` for degenerate points.
    """
    import cv2

    px = np.asarray(reference_px, float)
    m = np.asarray(reference_m, float)
    fault = reference_fault(px, m)
    if fault:
        raise DataError(f"degenerate reference points: {fault}")
    if len(px) == 4:
        h = cv2.getPerspectiveTransform(px.astype(np.float32), m.astype(np.float32))
    else:
        h, _ = cv2.findHomography(px, m, 0)
    if h is None or not np.all(np.isfinite(h)) or abs(np.linalg.det(h)) < 1e-18:
        raise DataError("degenerate reference points: no homography maps them")
    return h / h[2, 2]


def apply_homography(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Map points ``(..., 2)`` through the homography; NaN points stay NaN."""
    pts = np.asarray(pts, float)
    flat = pts.reshape(-1, 2)
    w = flat @ h[:2, :2].T + h[:2, 2]
    d = flat @ h[2, :2] + h[2, 2]
    return (w / d[:, None]).reshape(pts.shape)


@dataclass(frozen=True)
class TrialFrame:
    """The trial frame in tank coordinates: origin, unit heading (+Y) and unit right (+X)."""

    origin_m: np.ndarray
    forward: np.ndarray

    @property
    def right(self) -> np.ndarray:
        """+X: the heading turned 90 degrees clockwise seen from above."""
        return np.array([self.forward[1], -self.forward[0]])

    @property
    def heading_rad(self) -> float:
        """Angle of the heading in the tank frame, counter-clockwise from tank +X."""
        return float(np.arctan2(self.forward[1], self.forward[0]))

    def to_trial(self, xy_m: np.ndarray) -> np.ndarray:
        """Tank positions ``(..., 2)`` to trial-frame ``(X, Y)``."""
        d = np.asarray(xy_m, float) - self.origin_m
        return np.stack([d @ self.right, d @ self.forward], axis=-1)

    def to_tank(self, xy_trial: np.ndarray) -> np.ndarray:
        """Trial-frame ``(X, Y)`` back to tank positions."""
        p = np.asarray(xy_trial, float)
        return self.origin_m + p[..., :1] * self.right + p[..., 1:2] * self.forward


def trial_frame(origin_m, heading_vec) -> TrialFrame:
    """A trial frame from the robot's position and tail-to-head direction at ``start_s``."""
    f = np.asarray(heading_vec, float)
    n = float(np.hypot(*f))
    if not np.isfinite(n) or n == 0:
        raise DataError("cannot tell the robot's heading at start_s (markers coincide)")
    return TrialFrame(origin_m=np.asarray(origin_m, float).copy(), forward=f / n)
