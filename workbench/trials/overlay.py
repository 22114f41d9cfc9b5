"""An overlay video per trial for checking the tracking by eye.

Each frame shows the detected markers (head ring, tail ring, a cross when missing), the trail of
detected positions and the time since ``start_s``; a closing card of ``card_s`` seconds shows the
cleaned trajectory, the trial frame's axes, the 0.25 m stations or the fitted circle, and the
scores. Written at most ``overlay_width_px`` wide with OpenCV's mp4v encoder.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from workbench.errors import DataError

_HEAD = (0, 0, 255)
_TAIL = (255, 128, 0)
_TRAIL = (0, 255, 255)
_TEXT = (255, 255, 255)


class OverlayWriter:
    """Draw and encode overlay frames; call :meth:`add` per frame and :meth:`finish` once."""

    def __init__(self, path: str | Path, fps: float, size_wh: tuple[int, int], width_px: int, title: str):
        import cv2

        self.path = Path(path)
        self.scale = min(1.0, float(width_px) / size_wh[0])
        self.font = 0.45 * max(0.6, self.scale * size_wh[0] / 640)
        self.size = (max(2, int(round(size_wh[0] * self.scale)) // 2 * 2), max(2, int(round(size_wh[1] * self.scale)) // 2 * 2))
        self.fps = fps
        self.title = title
        self.trail: list[tuple[int, int]] = []
        self.last = None  # the last frame, resized, before drawing on it
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.writer = cv2.VideoWriter(str(self.path), cv2.VideoWriter_fourcc(*"mp4v"), fps, self.size)
        if not self.writer.isOpened():
            raise DataError("cannot open the overlay video for writing", path=self.path)

    def _small(self, frame):
        import cv2

        if frame.shape[1] == self.size[0] and frame.shape[0] == self.size[1]:
            return frame.copy()
        return cv2.resize(frame, self.size, interpolation=cv2.INTER_AREA)

    def _pt(self, uv) -> tuple[int, int]:
        # drawing with 4 fractional bits keeps sub-pixel positions visible
        return int(round((uv[0] + 0.5) * self.scale * 16 - 8)), int(round((uv[1] + 0.5) * self.scale * 16 - 8))

    def add(self, frame: np.ndarray, t_rel: float, head, tail, status: str = "") -> None:
        """Draw the detections of one frame and encode it."""
        import cv2

        img = self._small(frame)
        self.last = img.copy()
        for uv, col in ((head, _HEAD), (tail, _TAIL)):
            if np.all(np.isfinite(uv)):
                cv2.circle(img, self._pt(uv), int(6 * 16), col, 1, cv2.LINE_AA, 4)
        if np.all(np.isfinite(head)) and np.all(np.isfinite(tail)):
            self.trail.append(self._pt(0.5 * (np.asarray(head) + np.asarray(tail))))
            cv2.line(img, self._pt(tail), self._pt(head), _TRAIL, 1, cv2.LINE_AA, 4)
        elif self.trail:
            c = self.trail[-1]
            cv2.drawMarker(img, (c[0] // 16, c[1] // 16), (0, 0, 255), cv2.MARKER_TILTED_CROSS, 12, 2)
        if len(self.trail) > 1:
            pts = np.array(self.trail[-600:], np.int32)
            cv2.polylines(img, [pts], False, _TRAIL, 1, cv2.LINE_AA, 4)
        label = f"{self.title}  t = {t_rel:+6.2f} s  {status}"
        y = int(40 * self.font)
        cv2.putText(img, label, (8, y), cv2.FONT_HERSHEY_SIMPLEX, self.font, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, label, (8, y), cv2.FONT_HERSHEY_SIMPLEX, self.font, _TEXT, 1, cv2.LINE_AA)
        self.writer.write(img)

    def finish(self, card_lines: list[str], path_px: np.ndarray | None = None,
               extra_px: list[np.ndarray] | None = None, card_s: float = 2.0) -> Path:
        """Append the closing card (cleaned path, construction lines, scores) and close the file."""
        import cv2

        if self.last is not None:
            img = (self.last * 0.6).astype(np.uint8)
            for poly in extra_px or []:
                ok = np.all(np.isfinite(poly), axis=1)
                if ok.sum() > 1:
                    pts = np.array([self._pt(p) for p in poly[ok]], np.int32)
                    cv2.polylines(img, [pts], False, (255, 255, 255), 1, cv2.LINE_AA, 4)
            if path_px is not None:
                ok = np.all(np.isfinite(path_px), axis=1)
                if ok.sum() > 1:
                    pts = np.array([self._pt(p) for p in path_px[ok]], np.int32)
                    cv2.polylines(img, [pts], False, (0, 255, 0), 2, cv2.LINE_AA, 4)
            for k, line in enumerate(card_lines):
                y = int(40 * self.font * (1 + 0.9 * k))
                cv2.putText(img, line, (8, y), cv2.FONT_HERSHEY_SIMPLEX, self.font, (0, 0, 0), 3, cv2.LINE_AA)
                cv2.putText(img, line, (8, y), cv2.FONT_HERSHEY_SIMPLEX, self.font, _TEXT, 1, cv2.LINE_AA)
            for _ in range(max(1, int(round(card_s * self.fps)))):
                self.writer.write(img)
        self.writer.release()
        return self.path

    def abort(self) -> None:
        """Close and delete a half-written overlay."""
        self.writer.release()
        self.path.unlink(missing_ok=True)
