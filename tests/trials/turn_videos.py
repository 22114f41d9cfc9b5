"""An independent renderer of tight-turn trial videos for the turn-scoring tests.

It shares no code with the virtual pool or the scorer: its own pinhole camera (or a plain overhead
one), its own water texture and noise, markers drawn with OpenCV as projected discs, a dark body,
a pale "hand" hiding the markers for a few frames. The trajectory and its true scores are written
here in closed form, as data contract section 2 defines them:

* the body's centre runs a circle of radius ``r`` and its heading is the circle's tangent, so the
  circle fitted to a full turn has radius ``r``;
* the turn starts at ``start_s`` from rest, either at its full rate at once (``profile="step"``,
  360 degrees after ``2 pi / w``) or with the rate growing linearly over ``ramp_s``
  (``profile="ramp"``, 360 degrees after ``ramp_s / 2 + 2 pi / w``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: BGR of each contract colour name, as a printed sticker looks under pool light
COLOURS = {"red": (40, 35, 200), "green": (50, 170, 40), "blue": (190, 70, 30), "yellow": (40, 200, 215),
           "magenta": (170, 50, 190), "cyan": (190, 180, 40)}


@dataclass(frozen=True)
class TurnCase:
    """One rendered turn: radius, steady rate, direction (+1 left / counter-clockwise seen from above)."""

    id: str
    radius_m: float
    rate_deg_s: float
    direction: int
    profile: str = "step"
    ramp_s: float = 1.5
    start_s: float = 1.37
    #: (video time s, frames) when a hand hides both markers
    occlusions: tuple[tuple[float, int], ...] = ()
    #: start pose in the tank: x, y (m), heading (deg counter-clockwise from tank +X)
    start_pose: tuple[float, float, float] = (2.0, 2.5, 80.0)

    def theta(self, t: np.ndarray) -> np.ndarray:
        """Turned angle (rad, >= 0) at video times ``t``."""
        w = math.radians(self.rate_deg_s)
        s = np.maximum(np.asarray(t, float) - self.start_s, 0.0)
        if self.profile == "step":
            return w * s
        tr = self.ramp_s
        return np.where(s < tr, 0.5 * w * s**2 / tr, 0.5 * w * tr + w * (s - tr))

    @property
    def true_time_s(self) -> float:
        """Seconds after ``start_s`` at which the heading has changed by 360 degrees."""
        w = math.radians(self.rate_deg_s)
        return 2 * math.pi / w + (0.5 * self.ramp_s if self.profile == "ramp" else 0.0)

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body centre ``x, y`` (tank m) and heading (rad) at video times ``t``."""
        x0, y0, h0 = self.start_pose
        psi0 = math.radians(h0)
        d = self.direction
        # centre of the circle to the left of the start heading for a left turn
        cx = x0 + self.radius_m * math.cos(psi0 + d * math.pi / 2)
        cy = y0 + self.radius_m * math.sin(psi0 + d * math.pi / 2)
        phi = psi0 - d * math.pi / 2 + d * self.theta(t)
        return cx + self.radius_m * np.cos(phi), cy + self.radius_m * np.sin(phi), psi0 + d * self.theta(t)


@dataclass(frozen=True)
class StraightCase:
    """A straight run: from rest at ``start_s`` to ``speed`` at once, crabbing ``crab_deg`` off its heading.

    The body keeps its heading and moves along a line ``crab_deg`` to the left of it, so in the
    trial frame X = -Y tan(crab) exactly: the 2 m mark after ``2 / (speed cos(crab))`` s and an MAE
    over the stations Y = 0, 0.25, ..., 2 m of ``tan(crab) x mean(Y) = tan(crab) x 1.0 m``.
    """

    id: str
    speed_mps: float
    crab_deg: float
    start_s: float = 1.37
    occlusions: tuple[tuple[float, int], ...] = ()
    start_pose: tuple[float, float, float] = (2.0, 1.5, 90.0)

    @property
    def true_time_s(self) -> float:
        return 2.0 / (self.speed_mps * math.cos(math.radians(self.crab_deg)))

    @property
    def true_mae_m(self) -> float:
        return math.tan(math.radians(abs(self.crab_deg))) * 1.0

    def pose(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        x0, y0, h0 = self.start_pose
        psi0 = math.radians(h0)
        s = self.speed_mps * np.maximum(np.asarray(t, float) - self.start_s, 0.0)
        d = psi0 + math.radians(self.crab_deg)
        return x0 + s * math.cos(d), y0 + s * math.sin(d), np.full(np.shape(t), psi0)


@dataclass(frozen=True)
class Camera:
    """``project(points (N, 2) tank m) -> (N, 2) px``; ``kind`` "perspective" or "plain"."""

    kind: str
    width_px: int
    height_px: int
    centre_m: tuple[float, float]
    px_per_m: float
    params: dict = field(default_factory=dict)

    def project(self, xy: np.ndarray) -> np.ndarray:
        xy = np.asarray(xy, float).reshape(-1, 2)
        cx, cy = self.centre_m
        if self.kind == "plain":
            # straight down, tank +Y up the image, +X to the right
            u = self.width_px / 2 + self.px_per_m * (xy[:, 0] - cx)
            v = self.height_px / 2 - self.px_per_m * (xy[:, 1] - cy)
            return np.column_stack([u, v])
        # a pinhole camera behind and above the region, tilted down, slightly rolled
        tilt = math.radians(self.params.get("tilt_deg", 35.0))
        roll = math.radians(self.params.get("roll_deg", 3.0))
        height = self.params.get("height_m", 2.5)
        back = height * math.tan(tilt)
        c = np.array([cx - 0.3 * back, cy - back, height])
        fwd = np.array([cx, cy, 0.0]) - c
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        cr, sr = math.cos(roll), math.sin(roll)
        right, down = cr * right + sr * down, -sr * right + cr * down
        rel = np.column_stack([xy - c[:2], -c[2] * np.ones(len(xy))])
        xc, yc, zc = rel @ right, rel @ down, rel @ fwd
        f = self.px_per_m * np.linalg.norm(np.array([cx, cy, 0.0]) - c)
        return np.column_stack([self.width_px / 2 + f * xc / zc, self.height_px / 2 + f * yc / zc])

    def references(self) -> tuple[list[list[float]], list[list[float]]]:
        """Four surveyed points around the region (tank m) and where the camera sees them (px)."""
        cx, cy = self.centre_m
        hw, hh = 0.3 * self.width_px / self.px_per_m, 0.3 * self.height_px / self.px_per_m
        m = [[cx - hw, cy - hh], [cx + hw, cy - hh], [cx + hw, cy + hh], [cx - hw, cy + hh]]
        px = self.project(np.array(m))
        return [[round(float(u), 3), round(float(v), 3)] for u, v in px], m


def _disc(cam: Camera, centre, radius_m, n=40) -> np.ndarray:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return cam.project(np.column_stack([centre[0] + radius_m * np.cos(a), centre[1] + radius_m * np.sin(a)]))


def _poly(img, pts_px, colour, shift=4):
    import cv2

    p = np.round(pts_px * (1 << shift)).astype(np.int32)
    cv2.fillPoly(img, [p], colour, lineType=cv2.LINE_AA, shift=shift)


def render_turn(path: Path, case: TurnCase, cam: Camera, *, fps: float, head: str, tail: str,
                post_s: float = 2.0, seed: int = 0, noise: float = 3.0, marker_d_m: float = 0.07,
                spacing_m: float = 0.24) -> None:
    """Write ``path`` (mp4v): the robot turning per ``case``, seen by ``cam``."""
    import cv2

    rng = np.random.default_rng(seed)
    w, h = cam.width_px, cam.height_px
    n = int(math.ceil((case.start_s + case.true_time_s + post_s) * fps))
    # water: pale teal, a slowly moving ripple pattern, a few floor lines; grey deck outside nothing
    uu, vv = np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)
    base = np.empty((h, w, 3), np.float32)
    base[...] = (150, 140, 115)
    for k in range(3):
        p0, p1 = cam.project(np.array([[case.start_pose[0] - 2 + k, 0.0], [case.start_pose[0] - 2 + k, 5.0]]))
        cv2.line(base, tuple(int(v) for v in p0), tuple(int(v) for v in p1), (110, 105, 90), 3, cv2.LINE_AA)
    kx, ky = rng.uniform(0.02, 0.05, 2)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
    assert writer.isOpened()
    hidden = np.zeros(n, bool)
    for t0, nf in case.occlusions:
        i0 = int(round(t0 * fps))
        hidden[i0:i0 + nf] = True
    ts = np.arange(n) / fps
    xs, ys, hs = case.pose(ts)
    try:
        for i in range(n):
            t = ts[i]
            ripple = 8.0 * np.outer(np.cos(ky * vv - 0.6 * t), np.sin(kx * uu + 0.9 * t))
            img = base + ripple[..., None]
            x, y, psi = xs[i], ys[i], hs[i]
            f = np.array([math.cos(psi), math.sin(psi)])
            r = np.array([f[1], -f[0]])
            body = np.array([[x, y]]) + np.array([[0.2, 0.11], [0.2, -0.11], [-0.2, -0.11], [-0.2, 0.11]]) @ np.array([f, r])
            _poly(img, cam.project(body), (45, 45, 50))
            c = np.array([x, y])
            _poly(img, _disc(cam, c + 0.5 * spacing_m * f, marker_d_m / 2), COLOURS[head])
            _poly(img, _disc(cam, c - 0.5 * spacing_m * f, marker_d_m / 2), COLOURS[tail])
            if hidden[i]:
                # a pale hand and forearm over the robot, reaching in from the image's bottom edge
                arm = np.array([[x - 0.15, y - 0.2], [x + 0.15, y - 0.2], [x + 0.2, y + 0.25], [x - 0.2, y + 0.25]])
                _poly(img, cam.project(arm), (165, 180, 200))
            img = cv2.GaussianBlur(img, (0, 0), 0.7)
            img += noise * rng.standard_normal(img.shape, dtype=np.float32)
            writer.write(np.clip(img, 0, 255).astype(np.uint8))
    finally:
        writer.release()


def write_folder(root: Path, cases: list, cam: Camera, *, fps: float, head: str = "magenta",
                 tail: str = "yellow", seed: int = 0) -> Path:
    """A contract trials folder (trials.toml + videos/) with one trial per case (turn or straight)."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "videos").mkdir(exist_ok=True)
    ref_px, ref_m = cam.references()
    lines = ['schema = "workbench/trials@1"', f'id = "{root.name}"', "", "[tank]", "width_m = 4.0",
             "length_m = 5.0", "", "[camera]", f"reference_px = {ref_px}", f"reference_m = {ref_m}", "",
             "[robot]", f'head_marker = "{head}"', f'tail_marker = "{tail}"']
    for k, c in enumerate(cases):
        render_turn(root / "videos" / f"{c.id}.mp4", c, cam, fps=fps, head=head, tail=tail, seed=seed + k)
        task = "straight" if isinstance(c, StraightCase) else "turn"
        lines += ["", "[[trials]]", f'id = "{c.id}"', f'task = "{task}"', 'model = "EF"', f"solution = {k + 1}",
                  f'video = "videos/{c.id}.mp4"', f"start_s = {c.start_s}"]
    (root / "trials.toml").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return root
