"""The virtual pool's renderer: the tilted camera, the tank scene and one trial's video.

A 4 m x 5 m tank seen by a tilted overhead camera (a pinhole camera looking down at the water
plane, so the tank appears as a perspective trapezoid), with a moving caustic water texture,
lane lines, moving glare patches, slow lighting drift, vignetting, sensor noise, motion blur of
the robot along its image motion, the robot (dark body, paddling legs, two coloured disc
markers) and brief occlusions by a passing arm and its shadow. :func:`render_trial` writes one
mp4v video from a tank-frame trajectory; :func:`render_all` renders a folder's trials in order,
in worker processes when asked (the bytes do not depend on it).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import numpy as np

from workbench.errors import ContractError, OutputError
from workbench.virtual_lab.pool_settings import MARKER_BGR, PoolSettings


@dataclass(frozen=True)
class TiltedCamera:
    """A pinhole camera above the tank; ``h_m2px`` maps the water plane (z = 0) to pixels."""

    width_px: int
    height_px: int
    h_m2px: np.ndarray
    k: np.ndarray
    r: np.ndarray
    t: np.ndarray

    @classmethod
    def looking_at(cls, s: PoolSettings) -> "TiltedCamera":
        """Place the camera at ``camera_position_m`` looking at ``camera_target_m``; fit the tank in the frame."""
        c = np.array(s.camera_position_m, float)
        f = np.array(s.camera_target_m, float) - c
        f /= np.linalg.norm(f)
        x = np.cross(f, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(f, x)
        roll = math.radians(s.camera_roll_deg)
        x, y = math.cos(roll) * x + math.sin(roll) * y, -math.sin(roll) * x + math.cos(roll) * y
        r = np.stack([x, y, f])
        t = -r @ c
        corners = np.array([[0, 0], [s.tank_width_m, 0], [s.tank_width_m, s.tank_length_m], [0, s.tank_length_m]], float)
        pc = (r[:, :2] @ corners.T).T + t
        if np.any(pc[:, 2] <= 0):
            raise ContractError("the pool camera does not see the whole tank (a corner is behind it)")
        n = pc[:, :2] / pc[:, 2:]
        lo, hi = n.min(axis=0), n.max(axis=0)
        m = s.frame_margin
        focal = min(s.width_px * (1 - 2 * m) / (hi[0] - lo[0]), s.height_px * (1 - 2 * m) / (hi[1] - lo[1]))
        cx = s.width_px / 2 - focal * (lo[0] + hi[0]) / 2
        cy = s.height_px / 2 - focal * (lo[1] + hi[1]) / 2
        k = np.array([[focal, 0, cx], [0, focal, cy], [0, 0, 1.0]])
        h = k @ np.column_stack([r[:, 0], r[:, 1], t])
        return cls(s.width_px, s.height_px, h / h[2, 2], k, r, t)

    def project(self, xy_m: np.ndarray) -> np.ndarray:
        """Water-plane points ``(..., 2)`` to pixels."""
        p = np.asarray(xy_m, float)
        flat = p.reshape(-1, 2)
        w = flat @ self.h_m2px[:, :2].T + self.h_m2px[:, 2]
        return (w[:, :2] / w[:, 2:]).reshape(p.shape)


class Scene:
    """Precomputed background layers and per-frame composition of one folder's look."""

    def __init__(self, s: PoolSettings, cam: TiltedCamera, rng: np.random.Generator):
        import cv2

        self.s, self.cam, self.rng = s, cam, rng
        w, h = s.width_px, s.height_px
        # world texture of the tank and deck, warped once into the image
        ppm = 1.4 * self._px_per_m()
        pad = 0.6
        tw = int(math.ceil((s.tank_width_m + 2 * pad) * ppm))
        tl = int(math.ceil((s.tank_length_m + 2 * pad) * ppm))
        # texture pixel (col, row) = ((x + pad) ppm, (y + pad) ppm)
        tex2m = np.array([[1 / ppm, 0, -pad], [0, 1 / ppm, -pad], [0, 0, 1]])
        self.h_tex2px = cam.h_m2px @ tex2m
        xs = (np.arange(tw) + 0.5) / ppm - pad
        ys = (np.arange(tl) + 0.5) / ppm - pad
        gx, gy = np.meshgrid(xs, ys)
        inside = (gx >= 0) & (gx <= s.tank_width_m) & (gy >= 0) & (gy <= s.tank_length_m)
        rim = 0.08
        deck = ~((gx >= -rim) & (gx <= s.tank_width_m + rim) & (gy >= -rim) & (gy <= s.tank_length_m + rim))
        tex = np.empty((tl, tw, 3), np.float32)
        tex[:] = (205, 205, 200)  # the tank's rim
        tex[deck] = (150, 158, 160)
        water = np.array([122, 118, 98], np.float32)
        tex[inside] = water
        # pool-floor lane lines seen through the water (dark, low saturation)
        lane = inside & ((np.abs(((gx + 0.5) % 1.0) - 0.5) < 0.025) | (np.abs(((gy + 0.25) % 1.0) - 0.5) < 0.015))
        tex[lane] = water * 0.8
        noise = cv2.GaussianBlur(rng.normal(0, 1, (tl, tw)).astype(np.float32), (0, 0), 3) * 25
        tex += noise[..., None] * np.where(deck, 1.0, 0.25)[..., None]
        self.base = cv2.warpPerspective(np.clip(tex, 0, 255).astype(np.uint8), self.h_tex2px, (w, h),
                                        flags=cv2.INTER_LINEAR, borderValue=(60, 60, 60))
        if s.vignetting > 0:
            yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
            rr = ((xx - w / 2) / (w / 2)) ** 2 + ((yy - h / 2) / (h / 2)) ** 2
            gain = (1 - s.vignetting * rr / 2)[..., None]
            self.base = np.clip(self.base * gain, 0, 255).astype(np.uint8)
        water_mask = cv2.warpPerspective(inside.astype(np.uint8) * 255, self.h_tex2px, (w, h))
        self.water_mask = water_mask
        self.caustics = self._caustics(tw, tl, ppm, pad, inside) if s.water_texture else []
        self.noise = [np.round(rng.normal(0, s.noise_sigma, (h, w, 3))).astype(np.int16) for _ in range(6)] \
            if s.noise_sigma > 0 else []
        self.glares = [self._glare_path() for _ in range(max(0, s.glare_patches))]
        self.sprite = self._glare_sprite()

    def _px_per_m(self) -> float:
        s = self.s
        c = self.cam.project(np.array([[0, 0], [s.tank_width_m, 0], [0, s.tank_length_m]], float))
        return max(np.hypot(*(c[1] - c[0])) / s.tank_width_m, np.hypot(*(c[2] - c[0])) / s.tank_length_m)

    def _caustics(self, tw, tl, ppm, pad, inside, n_frames=16, period_s=4.0):
        """A looping caustic net: bright ridges where a few travelling waves interfere."""
        import cv2

        s = self.s
        step = 2  # compute at half the texture resolution
        xs = (np.arange(0, tw, step) + 0.5) / ppm - pad
        ys = (np.arange(0, tl, step) + 0.5) / ppm - pad
        gx, gy = np.meshgrid(xs.astype(np.float32), ys.astype(np.float32))
        waves = []
        for _ in range(5):
            ang = self.rng.uniform(0, 2 * np.pi)
            kk = 2 * np.pi / self.rng.uniform(0.25, 0.6)
            waves.append((kk * np.cos(ang), kk * np.sin(ang), self.rng.uniform(0, 2 * np.pi),
                          int(self.rng.integers(1, 3))))
        small_inside = inside[::step, ::step][: gy.shape[0], : gx.shape[1]].astype(np.float32)
        layers = []
        for i in range(n_frames):
            ph = 2 * np.pi * i / n_frames
            acc = np.zeros_like(gx)
            for kx, ky, p0, cyc in waves:
                acc += np.cos(kx * gx + ky * gy + p0 + cyc * ph)
            ridge = np.clip(acc / len(waves) * 2.2, 0, None) ** 2
            ridge = (ridge / max(float(ridge.max()), 1e-6) * s.caustic_strength * small_inside)
            big = cv2.resize(ridge, (tw, tl), interpolation=cv2.INTER_LINEAR)
            img = cv2.warpPerspective(big, self.h_tex2px, (s.width_px, s.height_px), flags=cv2.INTER_LINEAR)
            layer = np.clip(img, 0, 255).astype(np.uint8)
            layers.append(cv2.merge([layer, layer, (layer * 0.9).astype(np.uint8)]))
        self.caustic_period_s = period_s
        return layers

    def _glare_path(self):
        s = self.s
        u0 = self.rng.uniform(0.2, 0.8) * s.width_px
        v0 = self.rng.uniform(0.25, 0.75) * s.height_px
        amp = self.rng.uniform(0.08, 0.2, 2) * np.array([s.width_px, s.height_px])
        per = self.rng.uniform(9.0, 20.0, 2)
        ph = self.rng.uniform(0, 2 * np.pi, 2)
        return u0, v0, amp, per, ph

    def _glare_sprite(self):
        s = self.s
        sx = max(6, int(0.06 * s.width_px))
        sy = max(3, int(0.02 * s.width_px))
        yy, xx = np.mgrid[-3 * sy:3 * sy + 1, -3 * sx:3 * sx + 1].astype(np.float32)
        g = np.exp(-0.5 * ((xx / sx) ** 2 + (yy / sy) ** 2)) * s.glare_strength
        return np.repeat(g[..., None], 3, axis=2).astype(np.uint8)

    def background(self, t: float) -> np.ndarray:
        """The empty tank at time ``t`` with its moving caustics."""
        import cv2

        frame = self.base.copy()
        if self.caustics:
            pos = (t / self.caustic_period_s % 1.0) * len(self.caustics)
            i = int(pos)
            a = pos - i
            layer = cv2.addWeighted(self.caustics[i], 1 - a, self.caustics[(i + 1) % len(self.caustics)], a, 0)
            frame = cv2.add(frame, layer)
        return frame

    def glare(self, frame: np.ndarray, t: float) -> None:
        """Add the moving glare patches (reflections on the surface, so over the robot too), in place."""
        for u0, v0, amp, per, ph in self.glares:
            u = u0 + amp[0] * math.sin(2 * math.pi * t / per[0] + ph[0])
            v = v0 + amp[1] * math.sin(2 * math.pi * t / per[1] + ph[1])
            _add_sprite(frame, self.sprite, u, v)

    def finish(self, frame: np.ndarray, t: float, rng: np.random.Generator) -> np.ndarray:
        """Glare, lighting drift and sensor noise on a composed frame (``rng`` picks the noise frame)."""
        import cv2

        s = self.s
        self.glare(frame, t)
        if s.lighting_drift > 0:
            g = 1 + s.lighting_drift * (math.sin(2 * math.pi * t / 23.0 + 0.7) + 0.5 * math.sin(2 * math.pi * t / 7.3))
            frame = cv2.convertScaleAbs(frame, alpha=g)
        if self.noise:
            frame = cv2.add(frame, self.noise[int(rng.integers(len(self.noise)))], dtype=cv2.CV_8U)
        return frame


def _add_sprite(frame: np.ndarray, sprite: np.ndarray, u: float, v: float) -> None:
    import cv2

    h, w = sprite.shape[:2]
    x0, y0 = int(round(u - w / 2)), int(round(v - h / 2))
    fx0, fy0 = max(x0, 0), max(y0, 0)
    fx1, fy1 = min(x0 + w, frame.shape[1]), min(y0 + h, frame.shape[0])
    if fx1 <= fx0 or fy1 <= fy0:
        return
    roi = frame[fy0:fy1, fx0:fx1]
    cv2.add(roi, sprite[fy0 - y0:fy1 - y0, fx0 - x0:fx1 - x0], dst=roi)


@lru_cache(maxsize=8)
def _body_shapes(length: float, width: float, spacing: float, diameter: float):
    """Body, inner deck and marker outlines in the body frame (computed once per robot)."""
    half = spacing / 2
    return (_rounded_rect(length, width), _rounded_rect(length * 0.85, width * 0.6),
            _disc(0, half, diameter), _disc(0, -half, diameter))


def _rounded_rect(length: float, width: float, n: int = 6) -> np.ndarray:
    """Body outline (x right, y forward) with rounded corners."""
    r = 0.35 * width
    hx, hy = width / 2 - r, length / 2 - r
    pts = []
    for cx, cy, a0 in ((hx, hy, 0), (-hx, hy, 90), (-hx, -hy, 180), (hx, -hy, 270)):
        for a in np.linspace(a0, a0 + 90, n):
            pts.append((cx + r * math.cos(math.radians(a)), cy + r * math.sin(math.radians(a))))
    return np.array(pts)


def _disc(cx: float, cy: float, d: float, n: int = 20) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.column_stack([cx + d / 2 * np.cos(a), cy + d / 2 * np.sin(a)])


def _to_tank(poly_body: np.ndarray, x: float, y: float, yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.column_stack([x + c * poly_body[:, 0] - s * poly_body[:, 1], y + s * poly_body[:, 0] + c * poly_body[:, 1]])


def _draw_robot(frame, s: PoolSettings, cam: TiltedCamera, pose, vel_px, gait_phase: float, markers: bool) -> None:
    """Draw the robot (body, legs, markers) with motion blur along its image velocity, in place."""
    import cv2

    x, y, yaw = pose
    shapes = []
    body, deck, head, tail = _body_shapes(s.body_length_m, s.body_width_m, s.marker_spacing_m, s.marker_diameter_m)
    for k, (hx, hy) in enumerate(((-1, 1), (1, 1), (-1, -1), (1, -1))):
        # paddling legs: a swinging link out of each hip (LF, RF, LH, RH)
        ang = math.radians(35) * math.sin(gait_phase + k * math.pi / 2)
        base = np.array([hx * s.body_width_m * 0.45, hy * s.body_length_m * 0.3])
        d = np.array([hx * math.cos(ang), math.sin(ang)]) * 0.12
        nrm = np.array([-d[1], d[0]]) / np.hypot(*d) * 0.018
        leg = np.array([base + nrm, base + d + nrm, base + d - nrm, base - nrm])
        shapes.append((leg, (45, 48, 52)))
    shapes.append((body, (38, 40, 44)))
    shapes.append((deck, (60, 62, 66)))
    if markers:
        shapes.append((head, MARKER_BGR[s.head_marker]))
        shapes.append((tail, MARKER_BGR[s.tail_marker]))
    px = [(cam.project(_to_tank(poly, x, y, yaw)), col) for poly, col in shapes]
    allp = np.concatenate([p for p, _ in px])
    blur = np.asarray(vel_px, float) * s.exposure_fraction / s.fps if s.motion_blur else np.zeros(2)
    m = 4 + int(math.ceil(np.hypot(*blur)))
    x0, y0 = int(math.floor(allp[:, 0].min())) - m, int(math.floor(allp[:, 1].min())) - m
    x1, y1 = int(math.ceil(allp[:, 0].max())) + m, int(math.ceil(allp[:, 1].max())) + m
    fx0, fy0, fx1, fy1 = max(x0, 0), max(y0, 0), min(x1, frame.shape[1]), min(y1, frame.shape[0])
    if fx1 <= fx0 or fy1 <= fy0:
        return
    layer = np.zeros((y1 - y0, x1 - x0, 3), np.uint8)
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    for p, col in px:
        pts = np.round((p - [x0, y0]) * 16).astype(np.int32)
        # fill colour where this shape covers, replacing what lies under it
        cv2.fillPoly(layer, [pts], col, cv2.LINE_AA, 4)
        cv2.fillPoly(mask, [pts], 255, cv2.LINE_AA, 4)
    layer = layer.astype(np.float32)
    alpha = mask.astype(np.float32) / 255.0
    n = np.hypot(*blur)
    if n > 0.5:
        # a line kernel along the motion, centred so the blurred marker's centroid stays at mid-exposure
        size = int(math.ceil(n)) * 2 + 1
        kern = np.zeros((size, size), np.float32)
        c = size // 2
        for f in np.linspace(-0.5, 0.5, 4 * size):
            kern[int(round(c + f * blur[1])), int(round(c + f * blur[0]))] += 1
        kern /= kern.sum()
        layer = cv2.filter2D(layer, -1, kern, borderType=cv2.BORDER_CONSTANT)
        alpha = cv2.filter2D(alpha, -1, kern, borderType=cv2.BORDER_CONSTANT)
    roi = frame[fy0:fy1, fx0:fx1]
    sl = (slice(fy0 - y0, fy1 - y0), slice(fx0 - x0, fx1 - x0))
    out = roi.astype(np.float32) * (1 - alpha[sl][..., None]) + layer[sl]
    roi[:] = np.clip(out, 0, 255).astype(np.uint8)


def _draw_occluder(frame, s: PoolSettings, cam: TiltedCamera, pose, strength: float) -> None:
    """A pale arm reaching from the near deck over the robot, with its shadow (strength 0..1 fades it in)."""
    import cv2

    if strength <= 0:
        return
    x, y, yaw = pose
    hand = _to_tank(np.array([[0.18 * math.cos(a), 0.24 * math.sin(a)] for a in np.linspace(0, 2 * np.pi, 24)]),
                    x, y, yaw)
    start = np.array([-0.8, y - 0.3])
    d = np.array([x, y]) - start
    nrm = np.array([-d[1], d[0]]) / np.hypot(*d) * 0.06
    arm = np.array([start + nrm, [x, y] + nrm, [x, y] - nrm, start - nrm])
    for poly, col, off, a in ((hand, (0, 0, 0), 0.12, 0.45), (arm, (0, 0, 0), 0.12, 0.45),
                              (arm, (140, 158, 186), 0.0, 1.0), (hand, (140, 158, 186), 0.0, 1.0)):
        p = cam.project(poly + [off, -off])
        over = frame.copy()
        cv2.fillPoly(over, [np.round(p * 16).astype(np.int32)], col, cv2.LINE_AA, 4)
        cv2.addWeighted(over, a * strength, frame, 1 - a * strength, 0, dst=frame)



def render_trial(path: str | Path, t_s, x_m, y_m, yaw_rad, camera: TiltedCamera, settings: PoolSettings, *,
                 scene: "Scene | None" = None, start_s: float | None = None, duration_s: float | None = None,
                 gait_hz: float = 0.5, occlusions: Sequence[tuple[float, float]] = (), markers: bool = True,
                 seed: int = 0) -> dict:
    """Render one trial video from a tank-frame trajectory (t from the gait's start, x, y, yaw).

    Yaw is counter-clockwise from the robot facing tank +Y (body +y forward). The robot holds its
    start pose before ``start_s``. Returns the per-frame truth: video times, poses, occlusions.
    """
    import cv2

    s = settings
    rng = np.random.default_rng(seed)
    scene = scene or Scene(s, camera, np.random.default_rng(s.seed + 1))
    start_s = s.start_s if start_s is None else start_s
    t_s, x_m, y_m, yaw = (np.asarray(a, float) for a in (t_s, x_m, y_m, yaw_rad))
    duration_s = float(t_s[-1]) if duration_s is None else duration_s
    n = int(math.floor((start_s + duration_s) * s.fps)) + 1
    tv = np.arange(n) / s.fps
    tau = np.clip(tv - start_s, 0.0, t_s[-1])
    px, py, pyaw = np.interp(tau, t_s, x_m), np.interp(tau, t_s, y_m), np.interp(tau, t_s, yaw)
    centre = camera.project(np.column_stack([px, py]))
    vel = np.gradient(centre, tv, axis=0) if n > 1 else np.zeros_like(centre)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), s.fps, (s.width_px, s.height_px))
    if not writer.isOpened():
        raise OutputError("cannot open the video writer (mp4v)", path=path)
    occ_video = [(start_s + a, start_s + a + d) for a, d in occlusions]
    try:
        for i in range(n):
            t = tv[i]
            frame = scene.background(t)
            phase = 2 * math.pi * gait_hz * max(t - start_s, 0.0)
            _draw_robot(frame, s, camera, (px[i], py[i], pyaw[i]), vel[i], phase, markers)
            for a, b in occ_video:
                ramp = 0.12
                strength = min(1.0, max(0.0, min(t - (a - ramp), (b + ramp) - t) / ramp))
                _draw_occluder(frame, s, camera, (px[i], py[i], pyaw[i]), strength)
            writer.write(scene.finish(frame, t, rng))
    finally:
        writer.release()
    return {"video_time_s": tv, "x_m": px, "y_m": py, "yaw_rad": pyaw, "occlusions_s": occ_video}



def _render_job(args) -> dict:
    tmp, job, s, cam = args
    return render_trial(Path(tmp) / job["rel"], job["t_s"], job["x_m"], job["y_m"], job["yaw_rad"], cam, s,
                        duration_s=job["duration_s"], gait_hz=job["gait_hz"], occlusions=job["occlusions"],
                        markers=job["markers"], seed=job["seed"])


def render_all(tmp: Path, jobs: list[dict], s: PoolSettings, cam: TiltedCamera, scene: "Scene", workers: int):
    """Render the trials in order (yielding each truth record), in ``workers`` processes when > 1."""
    workers = max(1, min(workers, len(jobs), os.cpu_count() or 1))
    if workers == 1:
        for job in jobs:
            yield render_trial(tmp / job["rel"], job["t_s"], job["x_m"], job["y_m"], job["yaw_rad"], cam, s,
                               scene=scene, duration_s=job["duration_s"], gait_hz=job["gait_hz"],
                               occlusions=job["occlusions"], markers=job["markers"], seed=job["seed"])
        return
    from workbench.procs import process_pool  # workers die with this process; Ctrl-C ends them at once

    with process_pool(workers) as ex:
        yield from ex.map(_render_job, [(str(tmp), job, s, cam) for job in jobs])
