"""Reading trial videos with OpenCV: probing, and frames in order with their times.

Frame times are ``index / fps`` (the container's nominal rate); trial videos are expected at a
constant frame rate, as lab cameras record them. Frames the scorer does not need are only
grabbed (demuxed and decoded, not converted to BGR), which is cheaper than reading them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from workbench.errors import DataError


@dataclass(frozen=True)
class VideoInfo:
    """What the container says about a video."""

    path: Path
    fps: float
    n_frames: int
    width: int
    height: int

    @property
    def duration_s(self) -> float:
        """Time of the last frame plus one frame period."""
        return self.n_frames / self.fps


def _open(path: Path):
    import cv2

    if not path.is_file():
        raise DataError("video file not found", path=path)
    if path.stat().st_size == 0:
        raise DataError("empty file (0 bytes)", path=path, hint="copy the video again from the camera")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        cap.release()
        raise DataError("video cannot be opened (not a video OpenCV can decode, or a broken file)", path=path)
    return cap


def probe_video(path: str | Path) -> VideoInfo:
    """Frame rate, frame count and size; raises :class:`DataError` if the file is missing or unreadable."""
    import cv2

    path = Path(path)
    cap = _open(path)
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT) or 0)
        w = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH) or 0)
        h = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT) or 0)
        ok, frame = cap.read()
    finally:
        cap.release()
    if not ok or frame is None:
        raise DataError("video holds no decodable frame", path=path)
    if not np.isfinite(fps) or fps <= 0 or fps > 1000:
        raise DataError(f"video reports an unusable frame rate {fps!r}", path=path)
    if n <= 0:
        n = count_frames(path)
    return VideoInfo(path=path, fps=fps, n_frames=n, width=w or frame.shape[1], height=h or frame.shape[0])


def count_frames(path: str | Path) -> int:
    """Count frames by grabbing them all (for containers that do not say)."""
    cap = _open(Path(path))
    n = 0
    try:
        while cap.grab():
            n += 1
    finally:
        cap.release()
    return n


def frames(path: str | Path, first: int = 0, last: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
    """Yield ``(index, BGR frame)`` for frames ``first..last`` (inclusive), grabbing the ones before."""
    cap = _open(Path(path))
    try:
        i = 0
        while i < first:
            if not cap.grab():
                return
            i += 1
        while last is None or i <= last:
            ok, frame = cap.read()
            if not ok:
                return
            yield i, frame
            i += 1
    finally:
        cap.release()
