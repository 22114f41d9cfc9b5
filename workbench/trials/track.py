"""Frame-by-frame tracking of the head and tail markers (pure: frames in, pixel positions out).

Acquisition searches a shrunk copy of the whole frame for a head/tail blob pair whose spacing
on the water plane is plausible. Once locked, each frame is searched only in a small window
around the predicted markers at full resolution, which keeps tracking far cheaper than decoding.
A candidate is accepted when it is the right size on the water plane, nearest the prediction,
within the speed gate and keeps the head-tail spacing; otherwise the marker is missing in that
frame. Missing markers are filled later by :mod:`workbench.trials.clean`.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from workbench.trials.detect import Blob, ColourGate, find_blobs
from workbench.trials.geometry import apply_homography
from workbench.trials.params import ScoringSettings


class MarkerTracker:
    """Track two coloured markers; ``update(frame, t)`` returns head and tail pixel positions (NaN if missing)."""

    def __init__(self, h_px2m: np.ndarray, head: str, tail: str, params: ScoringSettings | None = None):
        self.p = params or ScoringSettings()
        self.h = np.asarray(h_px2m, float)
        mk = dict(hue_halfwidth=self.p.hue_halfwidth, sat_min=self.p.sat_min, val_min=self.p.val_min)
        self.gates = (ColourGate(head, **mk), ColourGate(tail, **mk))
        # under glare a marker keeps its hue but loses saturation: a second, laxer gate used only
        # close to a confident prediction
        mk["sat_min"] = self.p.sat_min_relaxed
        self.relaxed = (ColourGate(head, **mk), ColourGate(tail, **mk))
        self.n_relaxed = 0
        self.last_px: list[np.ndarray | None] = [None, None]
        self.last_m: list[np.ndarray | None] = [None, None]
        self.last_t: list[float] = [np.nan, np.nan]
        self.vel_px: list[np.ndarray] = [np.zeros(2), np.zeros(2)]
        self.spacings: deque[float] = deque(maxlen=31)
        self.locked = False
        self.missed = 0
        self.next_search_t = -np.inf
        self.n_searches = 0

    # --- geometry helpers -------------------------------------------------------------------
    def _to_m(self, uv) -> np.ndarray:
        return apply_homography(self.h, np.asarray(uv, float)[None])[0]

    def _m2_per_px2(self, uv) -> float:
        """Water-plane area of one pixel at ``uv`` (|det| of the homography's Jacobian)."""
        e = 0.5
        u, v = float(uv[0]), float(uv[1])
        pts = apply_homography(self.h, np.array([[u - e, v], [u + e, v], [u, v - e], [u, v + e]]))
        jac = np.column_stack([(pts[1] - pts[0]), (pts[3] - pts[2])]) / (2 * e)
        return abs(float(np.linalg.det(jac)))

    def _size_ok(self, b: Blob) -> bool:
        area_m2 = b.area_px * self._m2_per_px2((b.u, b.v))
        d = 2.0 * np.sqrt(area_m2 / np.pi)
        return self.p.marker_diameter_min_m <= d <= self.p.marker_diameter_max_m

    def _spacing_ok(self, head_m, tail_m) -> bool:
        s = float(np.hypot(*(head_m - tail_m)))
        if not (self.p.spacing_min_m <= s <= self.p.spacing_max_m):
            return False
        if len(self.spacings) >= 3:
            ref = float(np.median(self.spacings))
            return abs(s - ref) <= self.p.spacing_tolerance * ref
        return True

    # --- search -----------------------------------------------------------------------------
    def acquire(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """Search the whole frame for the best plausible head/tail pair: shrunk first, then at full size."""
        self.n_searches += 1
        k = max(1, int(self.p.downscale))
        for scale in dict.fromkeys((k, 1)):
            pair = self._search(frame, scale)
            if pair is not None:
                return pair
        return None

    def _search(self, frame: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray] | None:
        import cv2

        small = frame if k == 1 else cv2.resize(frame, (frame.shape[1] // k, frame.shape[0] // k),
                                                interpolation=cv2.INTER_AREA)
        hsv = cv2.cvtColor(small, cv2.COLOR_BGR2HSV)
        cands = []
        for gate in self.gates:
            blobs = [b for b in find_blobs(hsv, gate, scale=float(k), min_area_px=1.0) if self._size_ok(b)]
            cands.append(blobs[:12])
        best, best_score = None, -np.inf
        for hb in cands[0]:
            hm = self._to_m((hb.u, hb.v))
            for tb in cands[1]:
                tm = self._to_m((tb.u, tb.v))
                if not self._spacing_ok(hm, tm):
                    continue
                score = min(hb.area_px, tb.area_px) * (hb.saturation + tb.saturation)
                if score > best_score:
                    best, best_score = (hb, tb), score
        if best is None:
            return None
        # refine at full resolution around the coarse positions
        out = []
        for i, b in enumerate(best):
            r = self._roi_blobs(frame, [np.array([b.u, b.v])], which=(i,))[i]
            near = self._nearest(r, np.array([b.u, b.v]), radius_px=3.0 * k + 4)
            out.append(np.array([near.u, near.v]) if near is not None else np.array([b.u, b.v]))
        return out[0], out[1]

    def _margin_px(self, uv) -> float:
        scale = 1.0 / np.sqrt(max(self._m2_per_px2(uv), 1e-12))  # px per metre here
        return max(8.0, self.p.roi_margin_m * scale)

    def _roi_blobs(self, frame, centres, which=(0, 1), relaxed: bool = False) -> dict[int, list[Blob]]:
        """Blobs of the requested markers in one window covering the given centres."""
        import cv2

        pts = np.array(centres, float)
        m = max(self._margin_px(c) for c in pts)
        h, w = frame.shape[:2]
        x0 = int(max(0, np.floor(pts[:, 0].min() - m)))
        x1 = int(min(w, np.ceil(pts[:, 0].max() + m) + 1))
        y0 = int(max(0, np.floor(pts[:, 1].min() - m)))
        y1 = int(min(h, np.ceil(pts[:, 1].max() + m) + 1))
        if x1 - x0 < 2 or y1 - y0 < 2:
            return {i: [] for i in which}
        hsv = cv2.cvtColor(frame[y0:y1, x0:x1], cv2.COLOR_BGR2HSV)
        gates = self.relaxed if relaxed else self.gates
        return {i: [b for b in find_blobs(hsv, gates[i], offset=(x0, y0)) if self._size_ok(b)] for i in which}

    @staticmethod
    def _nearest(blobs: list[Blob], pred: np.ndarray, radius_px: float) -> Blob | None:
        best, dbest = None, radius_px
        for b in blobs:
            d = float(np.hypot(b.u - pred[0], b.v - pred[1]))
            if d <= dbest:
                best, dbest = b, d
        return best

    # --- per frame --------------------------------------------------------------------------
    def update(self, frame: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Process one BGR frame at time ``t`` (s); return head and tail ``(u, v)`` (NaN when missing)."""
        nan = np.array([np.nan, np.nan])
        found: list[np.ndarray | None] = [None, None]
        if self.locked:
            found = self._follow(frame, t)
        if not self.locked and t >= self.next_search_t:
            found = self._reacquire(frame, t, found)
        self._remember(found, t)
        return (found[0] if found[0] is not None else nan.copy(),
                found[1] if found[1] is not None else nan.copy())

    def _follow(self, frame: np.ndarray, t: float) -> list[np.ndarray | None]:
        """While locked: find each marker near its prediction; count misses and unlock after ``search_every_s``."""
        preds = self._predict(t)
        found = self._gated(self._roi_blobs(frame, preds), preds, t)
        missing = tuple(i for i in range(2) if found[i] is None)
        if missing and self.p.sat_min_relaxed < self.p.sat_min:
            self._relaxed_search(frame, preds, missing, found, t)
        self._check_spacing(found, preds, t)
        if found[0] is None and found[1] is None:
            self.missed += 1
        else:
            self.missed = 0
        if self.missed > 0 and t - np.nanmax(self.last_t) > self.p.search_every_s:
            self.locked = False
        return found

    def _predict(self, t: float) -> list[np.ndarray]:
        """Each marker's pixel position at ``t`` from its last position and velocity (at most 0.5 s ahead)."""
        preds = []
        for i in range(2):
            dt = t - self.last_t[i] if np.isfinite(self.last_t[i]) else 0.0
            preds.append(self.last_px[i] + self.vel_px[i] * min(dt, 0.5))
        return preds

    @staticmethod
    def _by_distance(blobs: list[Blob], pred: np.ndarray) -> list[Blob]:
        return sorted(blobs, key=lambda b: np.hypot(b.u - pred[0], b.v - pred[1]))

    def _gated(self, blobs: dict[int, list[Blob]], preds: list[np.ndarray], t: float) -> list[np.ndarray | None]:
        """For each marker the blob nearest its prediction that is within the speed gate of its last position."""
        found: list[np.ndarray | None] = [None, None]
        for i in range(2):
            dt = max(t - self.last_t[i], 1e-3)
            gate_m = self.p.max_speed_mps * dt + 0.03
            for b in self._by_distance(blobs[i], preds[i]):
                bm = self._to_m((b.u, b.v))
                if np.hypot(*(bm - self.last_m[i])) <= gate_m:
                    found[i] = np.array([b.u, b.v])
                    break
        return found

    def _relaxed_search(self, frame: np.ndarray, preds: list[np.ndarray], missing: tuple[int, ...],
                        found: list[np.ndarray | None], t: float) -> None:
        """Look for the missing markers with the laxer colour gate, accepting only blobs close to the prediction."""
        lax = self._roi_blobs(frame, [preds[i] for i in missing], which=missing, relaxed=True)
        for i in missing:
            dt = max(t - self.last_t[i], 1e-3)
            tight_m = 0.04 + 0.25 * self.p.max_speed_mps * dt
            pm = self._to_m(preds[i])
            for b in self._by_distance(lax[i], preds[i]):
                if np.hypot(*(self._to_m((b.u, b.v)) - pm)) <= tight_m:
                    found[i] = np.array([b.u, b.v])
                    self.n_relaxed += 1
                    break

    def _check_spacing(self, found: list[np.ndarray | None], preds: list[np.ndarray], t: float) -> None:
        """Drop a found marker whose head-tail spacing is implausible (in place)."""
        if found[0] is not None and found[1] is not None:
            if not self._spacing_ok(self._to_m(found[0]), self._to_m(found[1])):
                # drop the one that strays further from its prediction
                d = [np.hypot(*(found[i] - preds[i])) for i in range(2)]
                found[int(np.argmax(d))] = None
        elif found[0] is not None or found[1] is not None:
            i = 0 if found[0] is not None else 1
            j = 1 - i
            if self.last_m[j] is not None and len(self.spacings) >= 3:
                s = float(np.hypot(*(self._to_m(found[i]) - self.last_m[j])))
                ref = float(np.median(self.spacings))
                # the partner is hidden, but the visible one must still sit near its old partner
                if abs(s - ref) > self.p.spacing_tolerance * ref + self.p.max_speed_mps * (t - self.last_t[j]):
                    found[i] = None

    def _reacquire(self, frame: np.ndarray, t: float, found: list[np.ndarray | None]) -> list[np.ndarray | None]:
        """Search the whole frame (every ``search_every_s``); lock onto a pair within the speed gate.

        Returns the pair when locked, else ``found`` unchanged.
        """
        self.next_search_t = t + self.p.search_every_s
        pair = self.acquire(frame)
        if pair is None:
            return found
        hm, tm = self._to_m(pair[0]), self._to_m(pair[1])
        ok = True
        for i, m in enumerate((hm, tm)):
            if self.last_m[i] is not None:
                dt = max(t - self.last_t[i], 1e-3)
                ok &= bool(np.hypot(*(m - self.last_m[i])) <= self.p.max_speed_mps * dt + 0.05)
        if not ok:
            return found
        self.locked = True
        self.missed = 0
        return [pair[0], pair[1]]

    def _remember(self, found: list[np.ndarray | None], t: float) -> None:
        """Update each found marker's last position and smoothed velocity, and the spacing history."""
        for i in range(2):
            if found[i] is not None:
                if self.last_px[i] is not None and np.isfinite(self.last_t[i]) and t > self.last_t[i]:
                    v = (found[i] - self.last_px[i]) / (t - self.last_t[i])
                    self.vel_px[i] = 0.5 * self.vel_px[i] + 0.5 * v
                self.last_px[i] = found[i]
                self.last_m[i] = self._to_m(found[i])
                self.last_t[i] = t
        if found[0] is not None and found[1] is not None:
            self.spacings.append(float(np.hypot(*(self.last_m[0] - self.last_m[1]))))
