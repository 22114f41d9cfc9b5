"""Robot constants for the full-body simulator: masses, leg placement, HAA rotation, body drag laws.

Frames (docs/conventions.md): the body frame has x to the right, y forward, z up, origin at the
metacenter (taken as the body centre). A left leg's load-cell frame is parallel to the body frame
before its HAA rotation; a right leg's load-cell frame is the mirror image (x -> -x), so one leg
force model serves all four legs. Every number lives in ``pipelines/robot.yaml``; the defaults
below are the same values, so tests and notebooks can build a robot without the file.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal, Mapping

import numpy as np

from workbench.errors import ContractError, ParamsError, SettingError

#: Leg order everywhere (arrays, gait files' alpha_rad): left-front, right-front, left-hind, right-hind.
LEG_NAMES = ("LF", "RF", "LH", "RH")

#: The paper's towing-tank fits (section III-D), F in N for v in m/s, towed over 0.1-0.35 m/s.
PAPER_FORWARD_DRAG = (9.997, -0.132, 0.334)
PAPER_LATERAL_DRAG = (15.571, 0.937, 0.055)
PAPER_SPEED_RANGE_MPS = (0.10, 0.35)

_MIRROR = np.diag([-1.0, 1.0, 1.0])
BELOW_RANGE_MODES = ("linear_to_zero", "as_fitted", "drop_intercept")


def rodrigues(axis, angle_rad: float) -> np.ndarray:
    """Rotation matrix about ``axis`` (normalised here) by ``angle_rad``: I + sin K + (1 - cos) K^2."""
    k = np.asarray(axis, float)
    norm = np.linalg.norm(k)
    if norm == 0:
        raise SettingError("rotation axis has zero length")
    k = k / norm
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle_rad) * kx + (1.0 - math.cos(angle_rad)) * (kx @ kx)


@dataclass(frozen=True)
class DragLaw:
    """Body drag along one axis: magnitude c2 v^2 + c1 v + c0 inside the towed speed range.

    Below the lowest towed speed there is no data; ``below_range`` says what to do there:
    ``linear_to_zero`` (default) goes linearly from the fit at the lowest towed speed to zero at
    rest, because a body at rest feels no drag and a fitted intercept (the paper's forward 0.334 N)
    is an artefact of fitting 0.1-0.35 m/s; ``as_fitted`` keeps the polynomial down to v = 0
    (discontinuous at rest: the sign flips with the velocity); ``drop_intercept`` treats c0 as a
    towing-tank artefact (``fit-drag`` flags an intercept clearly above zero as "drag at rest") and
    uses c2 v^2 + c1 v at every speed, continuous through rest. The magnitude is never negative.
    """

    coefficients: tuple[float, float, float]
    speed_range_mps: tuple[float, float] = PAPER_SPEED_RANGE_MPS
    below_range: str = "drop_intercept"

    def __post_init__(self):
        if self.below_range not in BELOW_RANGE_MODES:
            raise SettingError(f"below_range must be one of {BELOW_RANGE_MODES}, got {self.below_range!r}")

    def polynomial(self, speed) -> np.ndarray:
        """The fitted polynomial c2 v^2 + c1 v + c0 (no range handling)."""
        c2, c1, c0 = self.coefficients
        s = np.asarray(speed, float)
        return (c2 * s + c1) * s + c0

    def magnitude(self, speed) -> np.ndarray:
        """Drag magnitude (N) at a non-negative speed (m/s)."""
        s = np.abs(np.asarray(speed, float))
        mag = self.polynomial(s)
        if self.below_range == "drop_intercept":
            mag = mag - self.coefficients[2]
        elif self.below_range == "linear_to_zero":
            v0 = self.speed_range_mps[0]
            if v0 > 0:
                mag = np.where(s < v0, self.polynomial(v0) * s / v0, mag)
        return np.maximum(mag, 0.0)

    def force(self, velocity) -> np.ndarray:
        """Drag force (N) opposing a signed velocity (m/s)."""
        v = np.asarray(velocity, float)
        return -np.sign(v) * self.magnitude(v)


@dataclass(frozen=True)
class RobotSettings:
    """Everything the simulator needs to know about the robot (SI units, body frame).

    Sources: Pupper geometry (StanfordQuadruped ``pupper/Config.py``: legs 0.10 m fore/aft of
    the centre, HAA joints 0.04 m off the centre line, leg plane 0.03 m outboard of the HAA axis);
    the paper for the HAA angles (front legs 30 deg, hind legs 0) and the body drag fits; estimates
    documented in docs/hydro.md for what the paper leaves out (mass, added masses, yaw inertia).
    """

    mass_kg: float = 2.0
    added_mass_forward_kg: float = 0.2
    added_mass_lateral_kg: float = 1.0
    yaw_inertia_kgm2: float = 0.033
    added_yaw_inertia_kgm2: float = 0.013
    #: include the Munk moment (m_x - m_y) v_x v_y that anisotropic added mass implies
    munk_moment: bool = True
    #: HAA joint positions from the metacenter, one row per leg in LEG_NAMES order
    haa_position_m: tuple[tuple[float, float, float], ...] = (
        (-0.04, 0.10, 0.0), (0.04, 0.10, 0.0), (-0.04, -0.10, 0.0), (0.04, -0.10, 0.0))
    #: HAA joint -> load-cell origin, in a left leg's unrotated frame (mirrored for right legs)
    hip_offset_m: tuple[float, float, float] = (-0.03, 0.0, 0.0)
    #: HAA rotation axis in the body frame (the paper's R = [r_x, 0, r_z], see docs/conventions.md)
    haa_axis: tuple[float, float, float] = (0.0, 1.0, 0.0)
    #: HAA angle per leg (deg); positive abducts (the foot swings outward and up) on both sides
    haa_angle_deg: tuple[float, float, float, float] = (30.0, 30.0, 0.0, 0.0)
    #: legs whose load-cell frame is the mirror image (x -> -x) of the measured leg's
    mirrored: tuple[bool, bool, bool, bool] = (False, True, False, True)
    forward_drag: DragLaw = field(default_factory=lambda: DragLaw(PAPER_FORWARD_DRAG))
    lateral_drag: DragLaw = field(default_factory=lambda: DragLaw(PAPER_LATERAL_DRAG))
    #: body length over which the lateral drag is spread to give yaw damping (cross-flow strips)
    body_length_m: float = 0.40
    strip_stations: int = 8
    #: extra linear yaw damping (N m s), on top of the strip-theory yaw drag
    extra_yaw_damping_nms: float = 0.0
    #: where the drag laws came from ("paper" or a drag.json path)
    drag_source: str = "paper"

    def __post_init__(self):
        if np.shape(self.haa_position_m) != (4, 3):
            raise SettingError("haa_position_m needs one [x, y, z] per leg (4 x 3)")
        if len(self.haa_angle_deg) != 4 or len(self.mirrored) != 4:
            raise SettingError("haa_angle_deg and mirrored need one entry per leg")
        if min(self.mass_kg, self.yaw_inertia_kgm2) <= 0:
            raise SettingError("mass_kg and yaw_inertia_kgm2 must be positive")
        if min(self.added_mass_forward_kg, self.added_mass_lateral_kg, self.added_yaw_inertia_kgm2,
               self.body_length_m, self.extra_yaw_damping_nms) < 0:
            raise SettingError("added masses, body length and yaw damping must be non-negative")
        if self.strip_stations < 1:
            raise SettingError("strip_stations must be at least 1")

    # -- effective inertia -------------------------------------------------------------------
    @property
    def mass_x_kg(self) -> float:
        """Mass resisting lateral (body x) acceleration: body + lateral added mass."""
        return self.mass_kg + self.added_mass_lateral_kg

    @property
    def mass_y_kg(self) -> float:
        """Mass resisting forward (body y) acceleration: body + forward added mass."""
        return self.mass_kg + self.added_mass_forward_kg

    @property
    def inertia_z_kgm2(self) -> float:
        """Yaw inertia including the added inertia."""
        return self.yaw_inertia_kgm2 + self.added_yaw_inertia_kgm2

    # -- legs --------------------------------------------------------------------------------
    def leg_rotations(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-leg 3x3 maps from load-cell to body frame for forces and for torques, each (4, 3, 3).

        Force map A = M R(axis, theta_A) for a mirrored leg (M = diag(-1, 1, 1)), R for the others.
        Torques are axial vectors, so a reflection flips them once more: the torque map is det(M) A.
        """
        forces, torques = [], []
        for angle, mirrored in zip(self.haa_angle_deg, self.mirrored, strict=True):
            a = rodrigues(self.haa_axis, math.radians(angle))
            if mirrored:
                a = _MIRROR @ a
            forces.append(a)
            torques.append(-a if mirrored else a)
        return np.stack(forces), np.stack(torques)

    def hip_positions_m(self) -> np.ndarray:
        """Each leg's load-cell origin from the metacenter (4, 3): HAA joint + rotated hip offset."""
        forces, _ = self.leg_rotations()
        return np.asarray(self.haa_position_m, float) + forces @ np.asarray(self.hip_offset_m, float)

    def leg_forward_axes(self) -> np.ndarray:
        """Each leg's load-cell +y (the direction it swims into the flow) in the body frame (4, 3)."""
        forces, _ = self.leg_rotations()
        return forces[:, :, 1]

    def with_drag(self, forward: DragLaw, lateral: DragLaw, source: str) -> "RobotSettings":
        """A copy with other body drag laws."""
        return replace(self, forward_drag=forward, lateral_drag=lateral, drag_source=source)

    def describe(self) -> dict:
        """A JSON-friendly record of the constants (for result files and MLflow)."""
        return {
            "mass_kg": self.mass_kg, "mass_x_kg": self.mass_x_kg, "mass_y_kg": self.mass_y_kg,
            "inertia_z_kgm2": self.inertia_z_kgm2, "munk_moment": self.munk_moment,
            "haa_position_m": [list(p) for p in self.haa_position_m], "hip_offset_m": list(self.hip_offset_m),
            "haa_axis": list(self.haa_axis), "haa_angle_deg": list(self.haa_angle_deg),
            "mirrored": [n for n, m in zip(LEG_NAMES, self.mirrored, strict=True) if m],
            "forward_drag": list(self.forward_drag.coefficients),
            "lateral_drag": list(self.lateral_drag.coefficients),
            "below_range": self.forward_drag.below_range, "body_length_m": self.body_length_m,
            "drag_source": self.drag_source,
        }


#: the name before issue 17 (settings classes end in ``Settings``); kept for existing imports
RobotParams = RobotSettings


# -- loading ---------------------------------------------------------------------------------
Leg = Literal["LF", "RF", "LH", "RH"]
Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class RobotBodySettings:
    """The ``robot`` section of pipelines/robot.yaml (a key left out: :class:`RobotSettings`'s default)."""

    mass_kg: float | None = None
    added_mass_forward_kg: float | None = None
    added_mass_lateral_kg: float | None = None
    yaw_inertia_kgm2: float | None = None
    added_yaw_inertia_kgm2: float | None = None
    munk_moment: bool | None = None


@dataclass(frozen=True)
class LegsSettings:
    """The ``legs`` section: per-leg values as a mapping ``{LF: .., RF: .., LH: .., RH: ..}`` or a list of 4."""

    haa_position_m: Mapping[str, Vec3] | tuple[Vec3, ...] | None = None
    hip_offset_m: Vec3 | None = None
    haa_axis: Vec3 | None = None
    haa_angle_deg: Mapping[str, float] | tuple[float, ...] | None = None
    mirrored: tuple[Leg, ...] | None = None


@dataclass(frozen=True)
class DragHeadingSettings:
    """One heading of ``body_drag`` (``forward`` or ``lateral``); no coefficients: the paper's."""

    coefficients: Vec3 | None = None
    speed_range_mps: tuple[float, float] = PAPER_SPEED_RANGE_MPS


@dataclass(frozen=True)
class BodyDragSettings:
    """The ``body_drag`` section."""

    drag_json: str | None = None
    forward: DragHeadingSettings = field(default_factory=DragHeadingSettings)
    lateral: DragHeadingSettings = field(default_factory=DragHeadingSettings)
    below_range: Literal["linear_to_zero", "as_fitted", "drop_intercept"] = "drop_intercept"
    #: None: :class:`RobotSettings`'s default
    body_length_m: float | None = None
    strip_stations: int | None = None
    extra_yaw_damping_nms: float | None = None


def _per_leg(value: Any, what: str, path) -> list:
    """A per-leg value given as a mapping {LF: .., ...} or a list in LEG_NAMES order."""
    from workbench.params import suggest

    if isinstance(value, Mapping):
        missing = [n for n in LEG_NAMES if n not in value]
        if missing:
            raise ParamsError(f"lacks legs {missing}", path=path, where=what, hint=f"one entry per leg {LEG_NAMES}")
        for name in value:
            if name not in LEG_NAMES:
                raise ParamsError(f"unknown leg '{name}'", path=path, where=f"{what}.{name}",
                                  hint=suggest(str(name), LEG_NAMES))
        return [value[n] for n in LEG_NAMES]
    if len(value) == 4:
        return list(value)
    raise ParamsError(f"needs one entry per leg {LEG_NAMES}, got {len(value)}", path=path, where=what)


def _leg_kwargs(legs: LegsSettings, path) -> dict[str, Any]:
    kwargs: dict[str, Any] = {}
    if legs.haa_position_m is not None:
        kwargs["haa_position_m"] = tuple(tuple(row) for row in _per_leg(legs.haa_position_m, "legs.haa_position_m", path))
    if legs.haa_angle_deg is not None:
        kwargs["haa_angle_deg"] = tuple(_per_leg(legs.haa_angle_deg, "legs.haa_angle_deg", path))
    if legs.hip_offset_m is not None:
        kwargs["hip_offset_m"] = legs.hip_offset_m
    if legs.haa_axis is not None:
        kwargs["haa_axis"] = legs.haa_axis
    if legs.mirrored is not None:
        kwargs["mirrored"] = tuple(n in legs.mirrored for n in LEG_NAMES)
    return kwargs


def read_drag_json(path: str | Path, below_range: str = "drop_intercept",
                   default_range: tuple[float, float] = PAPER_SPEED_RANGE_MPS) -> tuple[DragLaw, DragLaw]:
    """Forward and lateral drag laws from a ``drag.json`` (data contract section 4)."""
    from workbench.contract.jsonfile import read_json

    p = Path(path)
    doc = read_json(p, "drag file", hint="run `workbench fit-drag` first")
    laws = []
    for heading in ("forward", "lateral"):
        entry = doc.get(heading) if isinstance(doc, dict) else None
        coeffs = entry.get("coefficients") if isinstance(entry, dict) else None
        if not (isinstance(coeffs, list) and len(coeffs) == 3 and all(isinstance(c, (int, float)) for c in coeffs)):
            raise ContractError(f"'{heading}.coefficients' must be [c2, c1, c0]", path=p)
        rng = entry.get("speed_range_mps", default_range)
        laws.append(DragLaw(tuple(float(c) for c in coeffs), (float(rng[0]), float(rng[1])), below_range))
    return laws[0], laws[1]


def _drag_laws(drag: BodyDragSettings, drag_json: str | Path | None,
               path: str | Path | None) -> tuple[dict[str, DragLaw], str]:
    """The forward and lateral drag laws and where they come from.

    From ``drag_json`` when given (source: that file), else the section's coefficients (source
    ``"paper"`` when both are the paper's, else the parameter file).
    """
    laws = {heading: DragLaw(entry.coefficients or default, entry.speed_range_mps, drag.below_range)
            for heading, entry, default in (("forward", drag.forward, PAPER_FORWARD_DRAG),
                                            ("lateral", drag.lateral, PAPER_LATERAL_DRAG))}
    paper = laws["forward"].coefficients == PAPER_FORWARD_DRAG and laws["lateral"].coefficients == PAPER_LATERAL_DRAG
    source = "paper" if paper else str(path or "robot parameters")
    if drag_json:
        laws["forward"], laws["lateral"] = read_drag_json(drag_json, drag.below_range)
        source = str(drag_json)
    return laws, source


def robot_from_dict(doc: Mapping[str, Any], *, drag_json: str | Path | None = None,
                    path: str | Path | None = None) -> RobotSettings:
    """Build :class:`RobotSettings` from the parsed ``pipelines/robot.yaml`` (sections robot, legs, body_drag).

    Each section is built by :func:`workbench.params.build`: an unknown key or a value of the wrong
    type is a ParamsError naming the file and key path (``legs.haa_angel_deg``). ``drag_json`` (or
    ``body_drag.drag_json`` in the file) replaces the drag laws by a fitted ``drag.json``; otherwise
    the file's coefficients (the paper's by default) are used. Other top-level sections
    (``simulation``) are the simulator's.
    """
    from workbench.params import build

    if not isinstance(doc, Mapping):
        raise ParamsError("must be a mapping of sections (robot, legs, body_drag, simulation)", path=path)
    body = build(RobotBodySettings, doc.get("robot"), key="robot", path=path)
    legs = build(LegsSettings, doc.get("legs"), key="legs", path=path)
    drag = build(BodyDragSettings, doc.get("body_drag"), key="body_drag", path=path)
    laws, source = _drag_laws(drag, drag_json or drag.drag_json, path)
    try:
        given = {**dataclasses.asdict(body), "body_length_m": drag.body_length_m, "strip_stations": drag.strip_stations,
                 "extra_yaw_damping_nms": drag.extra_yaw_damping_nms}
        return RobotSettings(**{k: v for k, v in given.items() if v is not None}, **_leg_kwargs(legs, path),
                             forward_drag=laws["forward"], lateral_drag=laws["lateral"], drag_source=source)
    except SettingError as exc:  # a value checked by RobotSettings: the same error, with the file added
        raise exc.located(path=path) from None


def load_robot(path: str | Path = "pipelines/robot.yaml", *, drag_json: str | Path | None = None) -> RobotSettings:
    """Load the robot constants from a pipeline parameter file (and optionally a fitted drag.json)."""
    from workbench.params import read_document

    return robot_from_dict(read_document(path), drag_json=drag_json, path=path)
