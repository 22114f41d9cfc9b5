"""The virtual pool: open-water trial videos of known trajectories, written per data contract section 2.

A 4 m x 5 m tank seen by a tilted overhead camera (a pinhole camera looking down at the water
plane, so the tank appears as a perspective trapezoid), with a moving caustic water texture,
lane lines, moving glare patches, slow lighting drift, vignetting, sensor noise, motion blur of
the robot along its image motion, the robot (dark body, paddling legs, two coloured disc
markers) and brief occlusions by a passing arm and its shadow. Trajectories come from the
full-body simulator (``workbench.hydro.simulator``) run on the virtual lab's ground-truth leg
physics for the retained gaits of each model, or from the synthetic paths below.

Every folder gets ``truth.json`` (not part of the contract; readers ignore it): the camera,
the true trajectory at every frame, the occlusions, and the true scores computed from the true
trajectory with the contract's definitions, so the scorer can be checked against them.

``add_cli(subparsers)`` adds ``workbench virtual-lab pool``; ``generate_pool`` is the Python API.
"""

from __future__ import annotations

import json
import math
import os
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field, fields, replace
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from workbench.contract.trials import MARKER_COLOURS
from workbench.errors import ContractError, ModelError, WorkbenchError

#: BGR paint of each contract colour name (saturated, mid-bright: what a printed marker looks like).
MARKER_BGR = {"red": (40, 40, 205), "green": (60, 165, 35), "blue": (185, 75, 20), "yellow": (40, 195, 215),
              "magenta": (175, 50, 185), "cyan": (195, 185, 35)}
#: the paper's names of the models whose gaits are run (``lstmNN``: the FED-LSTM on NN-tick windows)
DEFAULT_LABELS = {"ef": "EF", "lstm": "FED-LSTM", "lstm16": "FED-LSTM-16"}


def model_display_label(model: str, labels: Mapping[str, str] | None = None) -> str:
    """The name a gait file's model gets in trials.toml and the scores.

    ``labels`` (the ``model_labels`` setting) first, then :data:`DEFAULT_LABELS`, then
    ``lstmNN`` -> ``FED-LSTM-NN`` (the FED-LSTM on NN-tick windows), else the name upper-cased.
    """
    import re

    if labels and model in labels:
        return str(labels[model])
    if model in DEFAULT_LABELS:
        return DEFAULT_LABELS[model]
    m = re.fullmatch(r"lstm[-_]?(\d+)", model)
    return f"FED-LSTM-{m.group(1)}" if m else model.upper()


# --- settings -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PoolSettings:
    """Every knob of the virtual pool (``pool`` section of pipelines/trials.yaml)."""

    trials_id: str = "demo-pool"
    seed: int = 0
    # video
    width_px: int = 640
    height_px: int = 360
    fps: float = 15.0
    #: video time at which the gait starts (off the frame grid on purpose)
    start_s: float = 1.03
    #: seconds recorded after the trial is decided
    post_s: float = 1.5
    # tank and camera (pinhole, looking from beyond the tank's X = 0 side, down at the water)
    tank_width_m: float = 4.0
    tank_length_m: float = 5.0
    camera_position_m: tuple[float, float, float] = (-1.8, 2.3, 3.6)
    camera_target_m: tuple[float, float, float] = (2.0, 2.6, 0.0)
    camera_roll_deg: float = 1.5
    #: fraction of the frame left free around the tank
    frame_margin: float = 0.03
    # robot
    body_length_m: float = 0.40
    body_width_m: float = 0.22
    marker_spacing_m: float = 0.24
    marker_diameter_m: float = 0.07
    head_marker: str = "red"
    tail_marker: str = "blue"
    draw_markers: bool = True
    # start poses in the tank: x, y (m) and heading (deg, counter-clockwise from tank +Y)
    straight_start: tuple[float, float, float] = (2.0, 1.2, 0.0)
    turn_start: tuple[float, float, float] = (2.0, 2.6, 30.0)
    start_jitter_m: float = 0.15
    start_jitter_deg: float = 8.0
    # effects
    water_texture: bool = True
    caustic_strength: float = 26.0
    glare_patches: int = 2
    glare_strength: float = 190.0
    lighting_drift: float = 0.10
    vignetting: float = 0.25
    noise_sigma: float = 4.0
    motion_blur: bool = True
    #: shutter open time as a fraction of the frame period
    exposure_fraction: float = 0.5
    #: fraction of trials that get one occlusion (at least one when > 0 and there are trials)
    occlusion_fraction: float = 0.5
    occlusion_duration_s: tuple[float, float] = (0.4, 0.9)
    # simulation of gaits
    models: tuple[str, ...] = ("ef", "lstm")
    tasks: tuple[str, ...] = ("straight", "turn")
    best: int = 2
    model_labels: Mapping[str, str] = field(default_factory=lambda: dict(DEFAULT_LABELS))
    #: the robot's physics in the pool: "truth" (the virtual lab's ground truth) or a leg-model spec
    physics: str = "truth"
    sim_dt_s: float = 1.0 / 65.0
    robot_params: str = "pipelines/robot.yaml"
    #: trials rendered in parallel (processes)
    workers: int = 2

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None, *, source: str = "pool params") -> "PoolSettings":
        """Build from a mapping (YAML), refusing unknown keys; lists become tuples."""
        m = dict(m or {})
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(m) - known)
        if unknown:
            raise ContractError(f"unknown pool parameter(s) {', '.join(unknown)}", path=source,
                                hint=f"known: {', '.join(sorted(known))}")
        out = {k: (tuple(v) if isinstance(v, list) else v) for k, v in m.items()}
        s = cls(**out)
        for name in (s.head_marker, s.tail_marker):
            if name not in MARKER_COLOURS:
                raise ContractError(f"marker colour {name!r} is not one of {MARKER_COLOURS}", path=source)
        if s.width_px < 64 or s.height_px < 64 or s.fps <= 0:
            raise ContractError("width_px, height_px must be >= 64 and fps positive", path=source)
        return s


# --- trajectories ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class PoolTrial:
    """One trial to render: a trajectory in the robot's start frame and its labels.

    ``t_s`` counts from the gait's start; ``x_m`` (right), ``y_m`` (forward) and ``yaw_rad``
    (counter-clockwise) are relative to the start pose, as the simulator's Trajectory gives them.
    """

    id: str
    task: str
    model: str
    solution: int
    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    yaw_rad: np.ndarray
    gait_hz: float = 0.5
    #: tank start pose (x, y, heading deg); None: the task's default with jitter
    start: tuple[float, float, float] | None = None
    #: occlusions as (start, duration) in seconds since the gait's start; None: drawn at random
    occlusions: tuple[tuple[float, float], ...] | None = None
    #: False renders the robot without markers (to test the scorer's error)
    markers: bool = True
    #: shorten the video to this many seconds after the gait's start (to test the scorer's error)
    video_until_s: float | None = None


def straight_path(speed_mps: float = 0.1, drift_deg: float = 3.0, wobble_m: float = 0.01, gait_hz: float = 0.5,
                  duration_s: float = 62.0, dt_s: float = 0.02, ramp_s: float = 2.0):
    """A straight swim with a constant heading drift (a slowly curving path) and gait-rate surge.

    Returns ``(t, x, y, yaw)`` in the start frame.
    """
    t = np.arange(0.0, duration_s + dt_s / 2, dt_s)
    ramp = np.clip(t / ramp_s, 0, 1) ** 2
    v = speed_mps * ramp * (1 + 0.3 * np.sin(2 * np.pi * gait_hz * t))
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))])
    # heading drifts by drift_deg per metre travelled (positive: to the left)
    yaw = np.radians(drift_deg) * s
    vx = -np.sin(yaw) * v
    vy = np.cos(yaw) * v
    x = np.concatenate([[0.0], np.cumsum(0.5 * (vx[1:] + vx[:-1]) * np.diff(t))])
    y = np.concatenate([[0.0], np.cumsum(0.5 * (vy[1:] + vy[:-1]) * np.diff(t))])
    x = x + wobble_m * np.sin(2 * np.pi * gait_hz * t) * ramp
    return t, x, y, yaw


def circle_path(radius_m: float = 0.08, period_s: float = 22.0, direction: int = 1, duration_s: float = 62.0,
                dt_s: float = 0.02, ramp_s: float = 2.0, drift_mps: float = 0.0):
    """Turning on the spot around a circle: the body's centre runs a circle of ``radius_m`` while it yaws.

    The robot swims forward along the circle's tangent (heading = path direction), completing one
    turn in about ``period_s`` once up to speed; ``direction`` +1 turns left, -1 right.
    """
    t = np.arange(0.0, duration_s + dt_s / 2, dt_s)
    # angular speed ramps up smoothly from rest
    w = direction * 2 * np.pi / period_s * np.clip(t / ramp_s, 0, 1) ** 2
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))])
    # centre of the circle to the left (turning left) of the start, on the start frame's x axis
    cx = -direction * radius_m
    x = cx + direction * radius_m * np.cos(yaw)
    y = direction * radius_m * np.sin(yaw)
    y = y + drift_mps * t
    return t, x, y, yaw


# --- camera -----------------------------------------------------------------------------------------
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


# --- the scene ---------------------------------------------------------------------------------------
class _Scene:
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


# --- rendering one trial ---------------------------------------------------------------------------
def _tank_trajectory(trial: PoolTrial, start, s: PoolSettings):
    """Start-frame trajectory -> tank frame (x, y, yaw), held at the walls of the tank."""
    x0, y0, h0 = start
    yaw0 = math.radians(h0)
    c, sn = math.cos(yaw0), math.sin(yaw0)
    x = x0 + c * trial.x_m - sn * trial.y_m
    y = y0 + sn * trial.x_m + c * trial.y_m
    r = 0.5 * max(s.body_length_m, s.body_width_m)
    clamped = bool(np.any((x < r) | (x > s.tank_width_m - r) | (y < r) | (y > s.tank_length_m - r)))
    x = np.clip(x, r, s.tank_width_m - r)
    y = np.clip(y, r, s.tank_length_m - r)
    return x, y, yaw0 + np.asarray(trial.yaw_rad, float), clamped


def true_scores(task: str, t_s, x_tank, y_tank, yaw_tank) -> dict:
    """The contract's scores of a true tank-frame trajectory (start at t = 0), as truth.json holds them."""
    from workbench.trials.geometry import trial_frame
    from workbench.trials.scoring import CAP_S, score_trajectory

    t = np.asarray(t_s, float)
    fwd0 = (-math.sin(yaw_tank[0]), math.cos(yaw_tank[0]))
    frame = trial_frame((x_tank[0], y_tank[0]), fwd0)
    xy = frame.to_trial(np.column_stack([x_tank, y_tank]))
    keep = t <= CAP_S + 1e-9
    sc = score_trajectory(task, t[keep], xy[keep, 0], xy[keep, 1], np.asarray(yaw_tank)[keep] - yaw_tank[0],
                          observed_until_s=float(t[-1]))
    return {"time_s": sc.time_s, "mae_x_m": sc.mae_x_m, "radius_m": sc.radius_m, "completed": sc.completed}


def render_trial(path: str | Path, t_s, x_m, y_m, yaw_rad, camera: TiltedCamera, settings: PoolSettings, *,
                 scene: "_Scene | None" = None, start_s: float | None = None, duration_s: float | None = None,
                 gait_hz: float = 0.5, occlusions: Sequence[tuple[float, float]] = (), markers: bool = True,
                 seed: int = 0) -> dict:
    """Render one trial video from a tank-frame trajectory (t from the gait's start, x, y, yaw).

    Yaw is counter-clockwise from the robot facing tank +Y (body +y forward). The robot holds its
    start pose before ``start_s``. Returns the per-frame truth: video times, poses, occlusions.
    """
    import cv2

    s = settings
    rng = np.random.default_rng(seed)
    scene = scene or _Scene(s, camera, np.random.default_rng(s.seed + 1))
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
        raise WorkbenchError("cannot open the video writer (mp4v)", path=path)
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


# --- a folder ------------------------------------------------------------------------------------
def _toml_value(v) -> str:
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, float):
        return repr(round(v, 4))
    return str(v)


def manifest_text(trials_id: str, s: PoolSettings, reference_px, reference_m, trials: Sequence[dict]) -> str:
    """trials.toml text per data contract section 2."""
    lines = ['schema = "workbench/trials@1"', f"id = {_toml_value(trials_id)}", "",
             "[tank]", f"width_m = {_toml_value(float(s.tank_width_m))}",
             f"length_m = {_toml_value(float(s.tank_length_m))}", "",
             "[camera]",
             f"reference_px = {_toml_value([[round(float(u), 2), round(float(v), 2)] for u, v in reference_px])}",
             f"reference_m = {_toml_value([[float(x), float(y)] for x, y in reference_m])}", "",
             "[robot]", f"head_marker = {_toml_value(s.head_marker)}", f"tail_marker = {_toml_value(s.tail_marker)}"]
    for t in trials:
        lines += ["", "[[trials]]"] + [f"{k} = {_toml_value(v)}" for k, v in t.items()]
    return "\n".join(lines) + "\n"


def _occlusions_for(trial: PoolTrial, decided_s: float, rng, s: PoolSettings, want: bool):
    if trial.occlusions is not None:
        return tuple(trial.occlusions)
    if not want:
        return ()
    dur = float(rng.uniform(*s.occlusion_duration_s))
    lo, hi = 2.0, max(2.5, decided_s - dur - 1.5)
    return ((float(rng.uniform(lo, hi)), dur),)


def _render_job(args) -> dict:
    tmp, job, s, cam = args
    return render_trial(Path(tmp) / job["rel"], job["t_s"], job["x_m"], job["y_m"], job["yaw_rad"], cam, s,
                        duration_s=job["duration_s"], gait_hz=job["gait_hz"], occlusions=job["occlusions"],
                        markers=job["markers"], seed=job["seed"])


def _render_all(tmp: Path, jobs: list[dict], s: PoolSettings, cam: TiltedCamera, scene: "_Scene", workers: int):
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


def generate_pool(out_dir: str | Path, trials: Sequence[PoolTrial] | None = None, *,
                  settings: PoolSettings | None = None, progress: bool = True, workers: int | None = None) -> Path:
    """Write a trials folder (trials.toml, videos/, truth.json) for the given trajectories.

    Without ``trials`` a synthetic set is rendered (see :func:`synthetic_trials`). The folder is
    built beside the target and swapped in at the end, so a failure leaves the old one intact.
    Trials render in ``workers`` processes (default ``settings.workers``); the bytes do not
    depend on it.
    """
    from workbench.atomic import atomic_dir
    from workbench.console import progress as progress_bar

    s = settings or PoolSettings()
    workers = s.workers if workers is None else workers
    out = Path(out_dir)
    trials = list(trials) if trials is not None else synthetic_trials(s)
    if not trials:
        raise ContractError("no trials to render", path=out)
    ids = [t.id for t in trials]
    if len(set(ids)) != len(ids):
        raise ContractError("duplicate trial ids", path=out)
    rng = np.random.default_rng(s.seed)
    cam = TiltedCamera.looking_at(s)
    scene = _Scene(s, cam, np.random.default_rng(s.seed + 1))
    corners = [(0.0, 0.0), (s.tank_width_m, 0.0), (s.tank_width_m, s.tank_length_m), (0.0, s.tank_length_m)]
    ref_px = cam.project(np.array(corners))
    n_occ = int(math.ceil(s.occlusion_fraction * len(trials))) if s.occlusion_fraction > 0 else 0
    occluded = set(rng.choice(len(trials), size=min(n_occ, len(trials)), replace=False).tolist()) if n_occ else set()
    jobs, entries, truth_trials = [], [], {}
    for k, tr in enumerate(trials):
        default = s.straight_start if tr.task == "straight" else s.turn_start
        start = tr.start or (default[0] + rng.uniform(-1, 1) * s.start_jitter_m,
                             default[1] + rng.uniform(-1, 1) * s.start_jitter_m,
                             default[2] + rng.uniform(-1, 1) * s.start_jitter_deg)
        x, y, yaw, clamped = _tank_trajectory(tr, start, s)
        sc = true_scores(tr.task, tr.t_s, x, y, yaw)
        length = min(sc["time_s"] + max(s.post_s, 2.0 / s.fps), float(tr.t_s[-1]))
        if tr.video_until_s is not None:
            length = min(length, tr.video_until_s)
        occ = _occlusions_for(tr, sc["time_s"], rng, s, k in occluded)
        video = f"videos/{tr.id}.mp4"
        jobs.append(dict(rel=video, t_s=tr.t_s, x_m=x, y_m=y, yaw_rad=yaw, duration_s=length, gait_hz=tr.gait_hz,
                         occlusions=occ, markers=bool(tr.markers and s.draw_markers), seed=s.seed * 1000 + k))
        entries.append({"id": tr.id, "task": tr.task, "model": tr.model, "solution": int(tr.solution),
                        "video": video, "start_s": float(s.start_s)})
        truth_trials[tr.id] = {
            "task": tr.task, "model": tr.model, "solution": int(tr.solution),
            "start_pose": {"x_m": float(start[0]), "y_m": float(start[1]), "heading_deg": float(start[2])},
            "scores": sc, "clamped_at_wall": clamped, "markers_drawn": bool(tr.markers and s.draw_markers)}
    with atomic_dir(out) as tmp:
        ctx = progress_bar("rendering pool trials", total=len(trials)) if progress else nullcontext()
        with ctx as bar:
            for tid, rec in zip(ids, _render_all(tmp, jobs, s, cam, scene, workers), strict=True):
                truth_trials[tid].update({
                    "occlusions_video_s": [[float(a), float(b)] for a, b in rec["occlusions_s"]],
                    "video_s": float(rec["video_time_s"][-1] + 1 / s.fps),
                    "frames": {"video_time_s": np.round(rec["video_time_s"], 6).tolist(),
                               "x_m": np.round(rec["x_m"], 6).tolist(), "y_m": np.round(rec["y_m"], 6).tolist(),
                               "yaw_rad": np.round(rec["yaw_rad"], 6).tolist()}})
                if bar:
                    bar.advance(1, tid)
        (tmp / "trials.toml").write_text(manifest_text(s.trials_id, s, ref_px, corners, entries), encoding="utf-8")
        truth = {"note": "virtual pool ground truth; not part of the data contract",
                 "seed": s.seed, "settings": _jsonable({k: v for k, v in asdict(s).items() if k != "workers"}),
                 "camera": {"h_m2px": cam.h_m2px.tolist(), "k": cam.k.tolist()},
                 "yaw_convention": "counter-clockwise from the robot facing tank +Y; body +y forward",
                 "trials": truth_trials}
        (tmp / "truth.json").write_text(json.dumps(truth) + "\n", encoding="utf-8")
    return out


def _jsonable(d):
    if isinstance(d, Mapping):
        return {k: _jsonable(v) for k, v in d.items()}
    if isinstance(d, (list, tuple)):
        return [_jsonable(v) for v in d]
    return d


def synthetic_trials(s: PoolSettings | None = None, seed: int | None = None) -> list[PoolTrial]:
    """A small synthetic set with paper-like speeds and radii.

    Per model ``best`` straight runs and turns; EF's second solution never finishes either task.
    """
    s = s or PoolSettings()
    rng = np.random.default_rng(s.seed if seed is None else seed)
    out = []
    for model in s.models:
        label = model_display_label(model, s.model_labels)
        for rank in range(1, s.best + 1):
            slow = model == "ef" and rank == 2
            t, x, y, yaw = straight_path(speed_mps=0.025 if slow else rng.uniform(0.08, 0.11),
                                         drift_deg=rng.uniform(-6, 6) * (2 if model == "ef" else 1),
                                         gait_hz=0.5)
            out.append(PoolTrial(f"{model}-straight-{rank}", "straight", label, rank, t, x, y, yaw))
            t, x, y, yaw = circle_path(radius_m=rng.uniform(0.05, 0.14), period_s=90 if slow else rng.uniform(20, 35),
                                       direction=1 if rank % 2 else -1)
            out.append(PoolTrial(f"{model}-turn-{rank}", "turn", label, rank, t, x, y, yaw))
    return out


# --- trajectories from gait files through the simulator ----------------------------------------
def read_gait_file(path: Path) -> dict:
    """A gait file (data contract section 5) with its solutions sorted by rank."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ContractError("gait file not found", path=path, hint="run `workbench optimize` first") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ContractError(f"not valid JSON: {exc}", path=path) from None
    sols = doc.get("solutions") if isinstance(doc, dict) else None
    if not isinstance(sols, list) or not sols:
        raise ContractError("no 'solutions' list", path=path)
    for i, sol in enumerate(sols):
        if not isinstance(sol, dict) or not isinstance(sol.get("params"), dict) or not isinstance(sol.get("rank"), int):
            raise ContractError(f"solution #{i + 1} needs an integer 'rank' and a 'params' table", path=path)
    doc["solutions"] = sorted(sols, key=lambda r: r["rank"])
    return doc


def simulated_trials(gaits_dir: str | Path, s: PoolSettings, *, on_progress=None) -> list[PoolTrial]:
    """Simulate the best ``s.best`` retained gaits of each model and task with the full-body simulator.

    The simulator's settings (fixed-point scheme, tolerance, iterations) come from the robot
    file's ``simulation`` section (pipelines/robot.yaml); the duration covers the 60 s cap plus
    ``post_s``. A trajectory whose fixed-point iteration did not converge is refused with a
    one-line ModelError naming the gait file and the solution: it is not a trial's truth.
    """
    try:
        from workbench.hydro.robot import RobotParams, load_robot
        from workbench.hydro.simulator import GaitBatch, simulate
    except ImportError as exc:
        raise ModelError(f"the full-body simulator is not available ({exc})",
                         hint="use --synthetic to render synthetic trajectories") from None
    from workbench.trials.scoring import CAP_S

    gaits_dir = Path(gaits_dir)
    # gaits that share the fixed constants (theta_h_max, theta_k_min, phi; the file's "fixed") swim together
    groups: dict[tuple, list[tuple[str, str, int, dict, Path]]] = {}
    for model in s.models:
        for task in s.tasks:
            path = gaits_dir / f"{task}-{model}.json"
            doc = read_gait_file(path)
            fixed = doc.get("fixed") if isinstance(doc.get("fixed"), dict) else {}
            key = tuple(sorted((k, float(v)) for k, v in fixed.items()
                               if k in ("theta_h_max_deg", "theta_k_min_deg", "phi_rad")))
            for sol in doc["solutions"][: s.best]:
                groups.setdefault(key, []).append((model, task, int(sol["rank"]), sol["params"], path))
    robot_path = Path(s.robot_params)
    robot = load_robot(robot_path) if robot_path.is_file() else RobotParams()
    settings = _sim_settings(robot_path)
    leg_model = _physics(s.physics)
    made: dict[tuple[str, str, int], PoolTrial] = {}
    for key, todo in groups.items():
        try:
            batch = GaitBatch.from_params([p for *_, p, _ in todo], **dict(key))
        except (ValueError, TypeError) as exc:
            raise ContractError(f"bad gait parameters: {exc}", path=gaits_dir) from None
        traj = simulate(batch, leg_model, robot, duration_s=CAP_S + s.post_s + 1.0, dt_s=s.sim_dt_s, **settings)
        for i, (model, task, rank, _, path) in enumerate(todo):
            if not traj.converged[i]:
                raise ModelError(
                    f"solution rank {rank}: the swim on '{s.physics}' physics did not converge (fixed-point "
                    f"residual {traj.residual_mps[i]:.2g} m/s, tolerance {settings.get('tol_mps', 1e-4):g}, "
                    f"{traj.iterations} leg-model calls)", path=path,
                    hint="its trajectory would be an artefact; see docs/hydro.md (simulation settings)")
            label = model_display_label(model, s.model_labels)
            made[(model, task, rank)] = PoolTrial(f"{model}-{task}-{rank}", task, label, rank, traj.t_s, traj.x_m[i],
                                                  traj.y_m[i], traj.yaw_rad[i], gait_hz=float(batch.frequency_hz[i]))
    # the order of the gait files (model, task, rank), whatever the grouping
    return [made[k] for k in sorted(made, key=lambda k: (s.models.index(k[0]), s.tasks.index(k[1]), k[2]))]


def _sim_settings(robot_path: Path) -> dict:
    """The robot file's fixed-point settings (scheme, tolerance, iterations), without duration and tick."""
    from workbench.hydro.simulator import simulation_settings

    if not robot_path.is_file():
        return {}
    from workbench.project import load_params

    try:
        doc = simulation_settings(load_params(robot_path).get("simulation"))
    except ValueError as exc:
        raise ContractError(str(exc), path=robot_path) from None
    return {k: v for k, v in doc.items() if k not in ("duration_s", "dt_s")}


def _physics(spec: str):
    if spec == "truth":
        from workbench.virtual_lab.physics import TrueLegModel

        return TrueLegModel()
    from workbench.hydro.legmodel import load_leg_model

    return load_leg_model(spec)


# --- command line --------------------------------------------------------------------------------
EXAMPLES = """\
  workbench virtual-lab pool datasets/raw/demo-pool --gaits datasets/gaits --params pipelines/trials.yaml
  workbench virtual-lab pool /tmp/pool --synthetic --fps 15 --size 640x360
  workbench virtual-lab pool /tmp/pool --gaits datasets/gaits --models ef lstm --best 8
  workbench virtual-lab pool /tmp/pool --gaits datasets/gaits --models ef lstm lstm16   # the 16-tick FED-LSTM too
  workbench score-trials /tmp/pool --out /tmp/pool-scores     # then compare with /tmp/pool/truth.json
"""


def add_cli(subparsers) -> None:
    """Add the ``pool`` subcommand to ``workbench virtual-lab``."""
    import argparse

    p = subparsers.add_parser(
        "pool", help="render an open-water trials folder (videos + trials.toml + truth.json)",
        description="Render overhead videos of the 4 m x 5 m tank from a tilted camera for the retained gaits "
        "of each model (simulated on the virtual lab's ground-truth physics) or for synthetic paths. "
        "Writes trials.toml per data contract section 2 and truth.json with the true scores.",
        epilog="examples:\n" + EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("out", type=Path, help="trials folder to write (replaced atomically)")
    p.add_argument("--gaits", type=Path, default=None, help="folder of <task>-<model>.json gait files")
    p.add_argument("--synthetic", action="store_true", help="render built-in synthetic trajectories instead")
    p.add_argument("--params", type=Path, default=None, help="YAML with a 'pool' section (pipelines/trials.yaml)")
    p.add_argument("--models", nargs="+", default=None,
                   help="model names of the gait files <task>-<model>.json, any number (default: the file's pool.models, "
                        "else ef lstm); trials are labelled by pool.model_labels, else ef EF, lstm FED-LSTM, "
                        "lstm16 FED-LSTM-16 (lstmNN: FED-LSTM-NN)")
    p.add_argument("--best", type=int, default=None, help="render the best N retained gaits per model and task")
    p.add_argument("--fps", type=float, default=None, help="video frame rate")
    p.add_argument("--size", default=None, help="video size WxH, e.g. 960x540")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--id", default=None, help="trials id written to trials.toml (default: folder name)")
    p.set_defaults(func=_run_cli)


def _run_cli(args) -> int:
    from workbench.console import info
    from workbench.project import load_params

    raw = load_params(args.params, "pool") if args.params else {}
    s = PoolSettings.from_mapping(raw, source=str(args.params or "defaults"))
    changes: dict[str, Any] = {"trials_id": args.id or args.out.name}
    if args.models:
        changes["models"] = tuple(args.models)
    if args.best is not None:
        changes["best"] = args.best
    if args.fps is not None:
        changes["fps"] = args.fps
    if args.seed is not None:
        changes["seed"] = args.seed
    if args.size:
        try:
            w, h = (int(v) for v in args.size.lower().split("x"))
        except ValueError:
            raise ContractError(f"--size must look like 960x540, got {args.size!r}") from None
        changes["width_px"], changes["height_px"] = w, h
    s = replace(s, **changes)
    if args.synthetic:
        trials = synthetic_trials(s)
    else:
        gaits = args.gaits or Path("datasets/gaits")
        info(f"simulating the best {s.best} gaits of {', '.join(s.models)} for {', '.join(s.tasks)} "
             f"on '{s.physics}' physics")
        trials = simulated_trials(gaits, s)
    out = generate_pool(args.out, trials, settings=s)
    info(f"wrote {len(trials)} trials to {out} (truth in {out / 'truth.json'})")
    return 0
