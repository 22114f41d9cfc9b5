"""trials.toml (contract section 2) parsed into frozen dataclasses, with every violation collected.

``check_trials`` returns the parsed folder and all violations; ``load_trials`` raises the first
folder-level one and hands trial-level ones back, so ``workbench score-trials`` can fail a bad
trial and still score the others.

One extension beyond the contract (optional, ignored by other readers): a trial may carry its own
``reference_px`` (and ``reference_m``) when the camera was bumped before it; otherwise the
folder's ``[camera]`` references apply.
"""

from __future__ import annotations

import itertools
import math
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from workbench.contract.columns import TRIALS_SCHEMA
from workbench.contract.unique import first_of_each_id
from workbench.errors import ContractError

#: Marker colour names the contract allows.
MARKER_COLOURS = ("red", "green", "blue", "yellow", "magenta", "cyan")
TASKS = ("straight", "turn")
VIDEO_SUFFIXES = (".mp4", ".avi")
_TRIAL_ID = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$"


@dataclass(frozen=True)
class TankSpec:
    """The ``[tank]`` table: world X spans the width, world Y the length (metres)."""

    width_m: float
    length_m: float


@dataclass(frozen=True)
class CameraSpec:
    """Reference points: pixel positions ``(N, 2)`` of points with known tank coordinates ``(N, 2)``."""

    reference_px: tuple[tuple[float, float], ...]
    reference_m: tuple[tuple[float, float], ...]

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(px, m)`` as float arrays of shape ``(N, 2)``."""
        return np.array(self.reference_px, float), np.array(self.reference_m, float)


@dataclass(frozen=True)
class RobotSpec:
    """The ``[robot]`` table: named colours of the head and tail markers."""

    head_marker: str
    tail_marker: str


@dataclass(frozen=True)
class TrialSpec:
    """One ``[[trials]]`` entry; ``video`` is resolved inside the folder, ``camera`` is its own or the folder's."""

    id: str
    task: str
    model: str
    solution: int
    video: Path
    start_s: float
    camera: CameraSpec


@dataclass(frozen=True)
class TrialsFolder:
    """A parsed open-water trials folder."""

    root: Path
    id: str
    tank: TankSpec
    camera: CameraSpec
    robot: RobotSpec
    trials: tuple[TrialSpec, ...]

    @property
    def manifest(self) -> Path:
        """Path of trials.toml."""
        return self.root / "trials.toml"

    def trial(self, trial_id: str) -> TrialSpec:
        """The trial with this id."""
        for t in self.trials:
            if t.id == trial_id:
                return t
        raise ContractError(f"no trial {trial_id!r}", path=self.manifest)


def trial_where(trial_id: str) -> str:
    """The ``where`` text naming a trial in error messages."""
    return f"trial {trial_id}"


class _Collector:
    def __init__(self, manifest: Path):
        self.manifest = manifest
        self.folder: list[ContractError] = []
        self.per_trial: dict[str, list[ContractError]] = {}

    def add(self, fault: str, *, where: str | None = None, hint: str | None = None):
        self.folder.append(ContractError(fault, path=self.manifest, where=where, hint=hint))

    def add_trial(self, tid: str, fault: str, *, hint: str | None = None):
        err = ContractError(fault, path=self.manifest, where=trial_where(tid), hint=hint)
        self.per_trial.setdefault(tid, []).append(err)


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    value = float(value)
    return value if math.isfinite(value) else None


def _points(value: Any, n: int | None = None) -> tuple[tuple[float, float], ...] | None:
    """A list of ``[a, b]`` number pairs, or None when malformed."""
    if not isinstance(value, list) or len(value) < 4 or (n is not None and len(value) != n):
        return None
    out = []
    for p in value:
        if not isinstance(p, list) or len(p) != 2:
            return None
        a, b = _number(p[0]), _number(p[1])
        if a is None or b is None:
            return None
        out.append((a, b))
    return tuple(out)


def reference_fault(px: np.ndarray, m: np.ndarray) -> str | None:
    """Why a set of reference points cannot define the water plane's homography, or None when usable.

    Checks: at least four pairs, no coincident points, no three nearly collinear (in either
    space), and a consistent orientation (a real camera maps the tank plane without folding it,
    so every triple keeps, or every triple flips, its turning direction).
    """
    if len(px) != len(m) or len(px) < 4:
        return f"need at least four reference point pairs, got {len(px)} pixel and {len(m)} metre points"
    for name, pts in (("reference_px", px), ("reference_m", m)):
        fault = _coincidence_fault(name, pts)
        if fault:
            return fault
    return _orientation_fault(px, m)


def _spread(pts: np.ndarray) -> float:
    """The largest distance between two of the points."""
    return float(np.max(np.linalg.norm(pts[:, None] - pts[None], axis=-1)))


def _coincidence_fault(name: str, pts: np.ndarray) -> str | None:
    """Why the points of one space coincide (all, or a pair closer than 1e-3 of their spread), or None."""
    spread = _spread(pts)
    if spread <= 0:
        return f"{name} points all coincide"
    for i, j in itertools.combinations(range(len(pts)), 2):
        if np.linalg.norm(pts[i] - pts[j]) < 1e-3 * spread:
            return f"{name} points {i + 1} and {j + 1} coincide"
    return None


def _turn_area(pts: np.ndarray, i: int, j: int, k: int, spread: float) -> float:
    """The signed area spanned by points i, j, k (its sign: their turning direction), over the spread squared."""
    d1, d2 = pts[j] - pts[i], pts[k] - pts[i]
    return (d1[0] * d2[1] - d1[1] * d2[0]) / spread**2


def _orientation_fault(px: np.ndarray, m: np.ndarray) -> str | None:
    """Why the triples are collinear or turn inconsistently between pixel and metre space, or None."""
    spreads = (_spread(px), _spread(m))
    signs = []
    n = len(px)
    for i, j, k in itertools.combinations(range(n), 3):
        areas = [_turn_area(pts, i, j, k, spread) for pts, spread in zip((px, m), spreads, strict=True)]
        smallest = min(abs(a) for a in areas)
        if n == 4 and smallest < 2e-3:
            return f"reference points {i + 1}, {j + 1}, {k + 1} are (nearly) collinear"
        if smallest > 2e-3:
            signs.append(np.sign(areas[0]) * np.sign(areas[1]))
    if not signs:
        return "reference points are all (nearly) collinear"
    if not (all(s > 0 for s in signs) or all(s < 0 for s in signs)):
        return "reference_px and reference_m list the points in inconsistent orders (the mapping folds the plane)"
    return None


def _camera(t: Any, col: _Collector, *, trial: str | None = None, base: CameraSpec | None = None) -> CameraSpec | None:
    where = "[camera]" if trial is None else None

    def add(fault, hint=None):
        if trial is None:
            col.add(fault, where=where, hint=hint)
        else:
            col.add_trial(trial, fault, hint=hint)

    if not isinstance(t, dict):
        add("missing [camera] table with reference_px and reference_m")
        return None
    px = _points(t.get("reference_px"))
    if px is None:
        add("reference_px must be a list of at least four [u, v] pixel pairs")
        return None
    if "reference_m" in t or base is None:
        m = _points(t.get("reference_m"), len(px))
        if m is None:
            add(f"reference_m must be a list of {len(px)} [x, y] pairs in metres, one per reference_px point")
            return None
    else:
        m = base.reference_m
        if len(m) != len(px):
            add(f"reference_px has {len(px)} points but the folder's reference_m has {len(m)}")
            return None
    fault = reference_fault(np.array(px, float), np.array(m, float))
    if fault:
        add(f"degenerate reference points: {fault}", hint="give four points with known tank coordinates, "
            "no three on a line, e.g. the tank corners in the same order in both lists")
        return None
    return CameraSpec(reference_px=px, reference_m=m)


def _resolve_video(root: Path, rel: Any, col: _Collector, tid: str) -> Path | None:
    if not isinstance(rel, str) or not rel:
        col.add_trial(tid, "'video' must be a relative path string")
        return None
    p = Path(rel)
    if p.is_absolute():
        col.add_trial(tid, f"video {rel!r} is absolute; paths must be relative to the trials folder")
        return None
    if not (root / p).resolve().is_relative_to(root.resolve()):
        col.add_trial(tid, f"video {rel!r} escapes the trials folder")
        return None
    if p.suffix.lower() not in VIDEO_SUFFIXES:
        col.add_trial(tid, f"video {rel!r} must be an .mp4 or .avi file")
        return None
    return root / p


def _parse_trial(i: int, t: Any, root: Path, camera: CameraSpec | None, col: _Collector) -> TrialSpec | None:
    where = f"[[trials]] #{i + 1}"
    if not isinstance(t, dict):
        col.add("trial entry is not a table", where=where)
        return None
    tid = t.get("id")
    if not isinstance(tid, str) or not re.match(_TRIAL_ID, tid):
        col.add(f"trial id {tid!r} is missing or not a simple name", where=where)
        return None
    n_before = len(col.per_trial.get(tid, []))
    task = t.get("task")
    if task not in TASKS:
        col.add_trial(tid, f"task must be one of {TASKS}, got {task!r}")
    model = t.get("model")
    if not isinstance(model, str) or not model.strip():
        col.add_trial(tid, "model must be a non-empty string (the model whose gait was run)")
    sol = t.get("solution")
    if not isinstance(sol, int) or isinstance(sol, bool) or sol < 1:
        col.add_trial(tid, f"solution must be a positive integer rank, got {sol!r}")
    start = _number(t.get("start_s"))
    if start is None or start < 0:
        col.add_trial(tid, f"start_s must be a non-negative number of seconds, got {t.get('start_s')!r}")
    video = _resolve_video(root, t.get("video"), col, tid)
    if video is not None and not video.is_file():
        col.add_trial(tid, f"video file {t.get('video')} not found")
    cam = camera
    if "reference_px" in t or "reference_m" in t:
        cam = _camera(t, col, trial=tid, base=camera)
    if len(col.per_trial.get(tid, [])) > n_before or cam is None:
        # keep a placeholder so the trial is reported, not silently dropped
        return TrialSpec(id=tid, task=str(task), model=str(model), solution=sol if isinstance(sol, int) else 0,
                         video=video or root / str(t.get("video")), start_s=start if start is not None else 0.0,
                         camera=cam or CameraSpec((), ()))
    return TrialSpec(id=tid, task=task, model=model.strip(), solution=sol, video=video, start_s=start, camera=cam)


def check_trials(root: str | Path) -> tuple[TrialsFolder | None, list[ContractError], dict[str, list[ContractError]]]:
    """Parse ``root/trials.toml``.

    Returns ``(folder, folder_errors, trial_errors)``: the folder (None when unusable), the
    violations that spoil the whole folder, and per trial id the violations that spoil only it.
    """
    root = Path(root)
    manifest = root / "trials.toml"
    col = _Collector(manifest)
    doc, unreadable = _read_manifest(root, manifest)
    if unreadable is not None:
        return None, [unreadable], {}
    schema = doc.get("schema")
    if schema != TRIALS_SCHEMA:
        col.add(f"unknown schema version {schema!r}", where="field schema", hint=f"this workbench reads {TRIALS_SCHEMA!r}")
        return None, col.folder, {}
    fid = _folder_id(doc, root, col)
    tank = _tank(doc.get("tank"), col)
    camera = _camera(doc.get("camera"), col)
    robot = _robot(doc.get("robot"), col)
    trials = _trials(doc.get("trials"), root, camera, col)
    if col.folder:
        folder = None if camera is None else TrialsFolder(root, fid, tank, camera, robot, tuple(trials))
        return folder, col.folder, col.per_trial
    return TrialsFolder(root=root, id=fid, tank=tank, camera=camera, robot=robot, trials=tuple(trials)), [], col.per_trial


def _read_manifest(root: Path, manifest: Path) -> tuple[dict | None, ContractError | None]:
    """``(document, None)`` for a readable trials.toml, else ``(None, the error that makes the folder unusable)``."""
    if not root.is_dir():
        return None, ContractError("trials folder does not exist", path=root)
    if not manifest.is_file():
        return None, ContractError("missing trials.toml", path=root)
    try:
        return tomllib.loads(manifest.read_text(encoding="utf-8-sig")), None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        return None, ContractError(f"not valid TOML: {exc}", path=manifest)


def _folder_id(doc: dict, root: Path, col: _Collector) -> str:
    """The folder's ``id``; when missing or blank, a violation and the folder's name."""
    fid = doc.get("id")
    if not isinstance(fid, str) or not fid.strip():
        col.add("id must be a non-empty string", where="field id")
        fid = root.name
    return fid


def _tank(tank_t: Any, col: _Collector) -> TankSpec:
    """The ``[tank]`` table (NaN sizes, and a violation, where a size is not a positive number)."""
    width = _number(tank_t.get("width_m")) if isinstance(tank_t, dict) else None
    length = _number(tank_t.get("length_m")) if isinstance(tank_t, dict) else None
    if width is None or width <= 0 or length is None or length <= 0:
        col.add("[tank] needs positive width_m and length_m", where="[tank]")
    return TankSpec(width_m=width or float("nan"), length_m=length or float("nan"))


def _robot(robot_t: Any, col: _Collector) -> RobotSpec:
    """The ``[robot]`` table; a violation for each marker not a contract colour, and for equal markers."""
    head = robot_t.get("head_marker") if isinstance(robot_t, dict) else None
    tail = robot_t.get("tail_marker") if isinstance(robot_t, dict) else None
    for key, val in (("head_marker", head), ("tail_marker", tail)):
        if val not in MARKER_COLOURS:
            col.add(f"{key} must be one of {', '.join(MARKER_COLOURS)}, got {val!r}", where=f"[robot] {key}")
    if head is not None and head == tail:
        col.add("head_marker and tail_marker must differ", where="[robot]")
    return RobotSpec(head_marker=str(head), tail_marker=str(tail))


def _trials(raw: Any, root: Path, camera: CameraSpec | None, col: _Collector) -> list[TrialSpec]:
    """The ``[[trials]]`` entries parsed, the first of each id kept; a violation for none and for each repeat."""
    if not isinstance(raw, list) or not raw:
        col.add("no [[trials]] entries", where="[[trials]]")
        raw = []
    return first_of_each_id(
        ((i, _parse_trial(i, t, root, camera, col)) for i, t in enumerate(raw)),
        lambda i, spec: col.add(f"duplicate trial id {spec.id!r}", where=f"[[trials]] #{i + 1}"))


def load_trials(root: str | Path) -> tuple[TrialsFolder, dict[str, list[ContractError]]]:
    """Parse a trials folder or raise its first folder-level violation; trial-level ones are returned."""
    folder, errors, per_trial = check_trials(root)
    if errors or folder is None:
        raise errors[0]
    return folder, per_trial
