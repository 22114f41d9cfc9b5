"""Coloured-marker detection on BGR frames (pure functions on arrays).

Colour is judged in HSV: hue picks the named colour and is unchanged by brightness; saturation
and value gates drop glare (bright but grey), shadowed water and the dark robot body. Blobs are
the connected components of the colour mask; their centroids are sub-pixel image moments.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Hue centre of each contract colour name in OpenCV's hue units (0-180 = 0-360 degrees).
HUE_CENTRES = {"red": 0, "yellow": 30, "green": 60, "cyan": 90, "blue": 120, "magenta": 150}


_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], np.uint8)


@dataclass(frozen=True)
class ColourGate:
    """HSV gates for one named colour."""

    name: str
    hue_halfwidth: int = 14
    sat_min: int = 90
    val_min: int = 50

    def ranges(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """``cv2.inRange`` bounds; red wraps around hue 0 and needs two."""
        c = HUE_CENTRES[self.name]
        lo, hi = c - self.hue_halfwidth, c + self.hue_halfwidth
        if lo < 0:
            spans = [(0, hi), (180 + lo, 179)]
        elif hi > 179:
            spans = [(lo, 179), (0, hi - 180)]
        else:
            spans = [(lo, hi)]
        out = []
        for a, b in spans:
            out.append((np.array([a, self.sat_min, self.val_min], np.uint8), np.array([b, 255, 255], np.uint8)))
        return out


@dataclass(frozen=True)
class Blob:
    """A candidate marker: centroid in full-frame pixels, area in pixels, mean saturation."""

    u: float
    v: float
    area_px: float
    saturation: float


def colour_mask(hsv: np.ndarray, gate: ColourGate) -> np.ndarray:
    """Binary mask (uint8 0/255) of pixels of this colour."""
    import cv2

    mask = None
    for lo, hi in gate.ranges():
        m = cv2.inRange(hsv, lo, hi)
        mask = m if mask is None else cv2.bitwise_or(mask, m)
    return mask


def find_blobs(hsv: np.ndarray, gate: ColourGate, *, offset=(0.0, 0.0), scale: float = 1.0,
               min_area_px: float = 2.0) -> list[Blob]:
    """Connected components of a colour in an HSV image (or ROI), largest first.

    ``offset`` is the ROI's top-left corner in the (possibly scaled) image; ``scale`` maps the
    image's pixels back to full-frame pixels (2.0 for a half-size image).
    """
    import cv2

    mask = colour_mask(hsv, gate)
    n, labels, stats, cents = cv2.connectedComponentsWithStats(mask, connectivity=8)
    blobs = []
    sat = hsv[..., 1]
    hh, ww = mask.shape
    for i in range(1, n):
        area = float(stats[i, cv2.CC_STAT_AREA])
        if area < min_area_px:
            continue
        x, y, w, h = stats[i, :4]
        # saturation-weighted centroid over the blob grown by one pixel: the partly covered rim
        # pixels pull the centre by how much of the marker they hold (sub-pixel, unlike a 0/1 mask)
        x0, y0, x1, y1 = max(x - 1, 0), max(y - 1, 0), min(x + w + 1, ww), min(y + h + 1, hh)
        grown = cv2.dilate((labels[y0:y1, x0:x1] == i).astype(np.uint8), _CROSS)
        wgt = sat[y0:y1, x0:x1].astype(np.float32) * grown
        tot = float(wgt.sum())
        if tot > 0:
            cu = float((wgt.sum(axis=0) * np.arange(x0, x1)).sum() / tot)
            cv = float((wgt.sum(axis=1) * np.arange(y0, y1)).sum() / tot)
        else:
            cu, cv = float(cents[i, 0]), float(cents[i, 1])
        s = float(sat[y:y + h, x:x + w][labels[y:y + h, x:x + w] == i].mean())
        # centroid of pixel centres, mapped to full-frame pixel coordinates
        u = (cu + offset[0] + 0.5) * scale - 0.5
        v = (cv + offset[1] + 0.5) * scale - 0.5
        blobs.append(Blob(u=float(u), v=float(v), area_px=area * scale * scale, saturation=s))
    blobs.sort(key=lambda b: -b.area_px)
    return blobs
