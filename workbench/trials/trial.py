"""Score one trial from its video: decode, track, clean, place the trial frame, score.

This is the trials package's reader: it opens the video; everything it calls works on arrays.
Any fault of this trial (video, markers, references, timing) raises a one-line
:class:`WorkbenchError` naming the trial, and the folder scorer records it and moves on.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from workbench.contract.trials import RobotSpec, TrialSpec, trial_where
from workbench.errors import DataError, WorkbenchError
from workbench.trials.clean import PoseSeries, clean_pose, start_heading, start_position_along
from workbench.trials.geometry import TrialFrame, apply_homography, plane_homography, trial_frame
from workbench.trials.params import ScoringSettings
from workbench.trials.scoring import (
    CAP_S,
    STATION_STEP_M,
    STRAIGHT_DISTANCE_M,
    TURN_RAD,
    TrialScore,
    UndecidedError,
    score_trajectory,
)
from workbench.trials.track import MarkerTracker
from workbench.trials.video import VideoInfo, frames, probe_video


@dataclass(frozen=True)
class TrialResult:
    """A scored trial: the scores, the cleaned pose, the trial frame and how the tracking went."""

    spec: TrialSpec
    score: TrialScore
    info: VideoInfo
    frame: TrialFrame
    pose: PoseSeries
    head_px: np.ndarray
    tail_px: np.ndarray
    #: frames decoded, detection and fill fractions, searches, seconds spent, overlay path
    stats: dict = field(default_factory=dict)

    def trajectory(self):
        """The per-frame trajectory as a polars frame (tank and trial coordinates, flags)."""
        import polars as pl

        t_rel = self.pose.t_s - self.spec.start_s
        xy = np.column_stack([self.pose.x_m, self.pose.y_m])
        trial_xy = self.frame.to_trial(xy)
        return pl.DataFrame({
            "frame": np.rint(self.pose.t_s * self.info.fps).astype(np.int64),
            "video_time_s": self.pose.t_s,
            "time_s": t_rel,
            "x_m": self.pose.x_m,
            "y_m": self.pose.y_m,
            "X_m": trial_xy[:, 0],
            "Y_m": trial_xy[:, 1],
            "heading_change_deg": np.degrees(self.pose.heading_rad - self.frame.heading_rad),
            "head_u_px": self.head_px[:, 0],
            "head_v_px": self.head_px[:, 1],
            "tail_u_px": self.tail_px[:, 0],
            "tail_v_px": self.tail_px[:, 1],
            "detected": self.pose.detected,
            "filled": self.pose.filled,
        })


def _fail(spec: TrialSpec, exc: WorkbenchError) -> WorkbenchError:
    """Re-raise an error with the trial named (and the video as the file when none is named)."""
    if exc.where and exc.where.startswith(trial_where(spec.id)):
        return exc
    path = exc.path or str(spec.video)
    where = trial_where(spec.id) if not exc.where else f"{trial_where(spec.id)}, {exc.where}"
    try:
        return type(exc)(exc.fault, path=path, run=exc.run, where=where, hint=exc.hint)
    except TypeError:
        return WorkbenchError(exc.fault, path=path, run=exc.run, where=where, hint=exc.hint)


class _Decider:
    """Online check of whether a trial is clearly decided, to stop decoding early (with margins)."""

    def __init__(self, task: str, start_s: float, h: np.ndarray):
        self.task, self.start_s, self.h = task, start_s, h
        self.seed: list[tuple[float, np.ndarray, np.ndarray]] = []
        self.frame: TrialFrame | None = None
        self.psi0 = 0.0
        self.psi = None
        self.decided_at: float | None = None

    def update(self, t: float, head, tail) -> None:
        if self.decided_at is not None or not (np.all(np.isfinite(head)) and np.all(np.isfinite(tail))):
            return
        hm, tm = apply_homography(self.h, np.array([head, tail]))
        if self.frame is None:
            if abs(t - self.start_s) <= 0.3:
                self.seed.append((t, hm, tm))
            if t > self.start_s + 0.3 and self.seed:
                mid = np.median([0.5 * (a + b) for _, a, b in self.seed], axis=0)
                d = np.median([a - b for _, a, b in self.seed], axis=0)
                self.frame = trial_frame(mid, d)
                self.psi0 = self.psi = math.atan2(d[1], d[0])
            return
        if self.task == "straight":
            if self.frame.to_trial(0.5 * (hm + tm))[1] >= STRAIGHT_DISTANCE_M + 0.1:
                self.decided_at = t
        else:
            ang = math.atan2(hm[1] - tm[1], hm[0] - tm[0])
            self.psi += (ang - self.psi + math.pi) % (2 * math.pi) - math.pi
            if abs(self.psi - self.psi0) >= TURN_RAD + math.radians(20):
                self.decided_at = t


def _track(spec: TrialSpec, robot: RobotSpec, info: VideoInfo, h: np.ndarray, p: ScoringSettings,
           early_stop: bool, overlay_path: Path | None):
    from workbench.trials.overlay import OverlayWriter

    fps = info.fps
    first = max(0, int(math.floor((spec.start_s - p.pre_start_s) * fps)))
    last = min(info.n_frames - 1, int(math.ceil((spec.start_s + CAP_S + p.smooth_window_s) * fps)))
    tracker = MarkerTracker(h, robot.head_marker, robot.tail_marker, p)
    decider = _Decider(spec.task, spec.start_s, h)
    ts, heads, tails = [], [], []
    writer = None
    if overlay_path is not None:
        writer = OverlayWriter(overlay_path, fps, (info.width, info.height), p.overlay_width_px,
                               f"{spec.id} ({spec.model} #{spec.solution}, {spec.task})")
    stopped_early = False
    try:
        for i, img in frames(info.path, first, last):
            t = i / fps
            head, tail = tracker.update(img, t)
            ts.append(t)
            heads.append(head)
            tails.append(tail)
            if writer is not None:
                writer.add(img, t - spec.start_s, head, tail, "" if tracker.locked else "searching")
            if early_stop:
                decider.update(t, head, tail)
                if decider.decided_at is not None and t >= decider.decided_at + p.stop_after_decided_s:
                    stopped_early = True
                    break
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    return (np.array(ts), np.array(heads).reshape(-1, 2), np.array(tails).reshape(-1, 2), writer,
            (tracker.n_searches, tracker.n_relaxed), stopped_early)


def score_trial(spec: TrialSpec, robot: RobotSpec, params: ScoringSettings | None = None, *,
                overlay_path: str | Path | None = None) -> TrialResult:
    """Score one trial; raises a :class:`WorkbenchError` naming the trial on any fault."""
    try:
        return _score_trial(spec, robot, params or ScoringSettings(),
                            None if overlay_path is None else Path(overlay_path))
    except WorkbenchError as exc:
        raise _fail(spec, exc) from None


def _score_trial(spec: TrialSpec, robot: RobotSpec, p: ScoringSettings, overlay_path: Path | None) -> TrialResult:
    t0 = time.perf_counter()
    info = probe_video(spec.video)
    if spec.start_s >= info.duration_s:
        raise DataError(f"start_s = {spec.start_s:g} s is past the video's end ({info.duration_s:.2f} s)")
    h = plane_homography(*spec.camera.arrays())
    early = p.early_stop
    while True:
        ts, heads, tails, writer, n_search, stopped_early = _track(spec, robot, info, h, p, early, overlay_path)
        try:
            result = _evaluate(spec, robot, p, info, h, ts, heads, tails)
        except BaseException:
            if writer is not None:
                writer.abort()
            raise
        if stopped_early and not result[0].completed:
            # the online check was fooled; decode the whole window instead
            if writer is not None:
                writer.abort()
            early = False
            continue
        break
    score, frame, pose = result
    stats = {
        "frames_decoded": int(ts.size),
        "detected_fraction": float(np.mean(pose.detected)) if ts.size else 0.0,
        "filled_fraction": float(np.mean(pose.filled)) if ts.size else 0.0,
        "full_frame_searches": int(n_search[0]),
        "relaxed_detections": int(n_search[1]),
        "stopped_early": bool(stopped_early),
        "seconds": 0.0,
        "overlay": None,
    }
    if writer is not None:
        stats["overlay"] = str(_finish_overlay(writer, spec, score, frame, pose, h))
    stats["seconds"] = time.perf_counter() - t0
    return TrialResult(spec=spec, score=score, info=info, frame=frame, pose=pose, head_px=heads,
                       tail_px=tails, stats=stats)


def _evaluate(spec, robot, p, info, h, ts, heads, tails) -> tuple[TrialScore, TrialFrame, PoseSeries]:
    n_found = int(np.sum(np.all(np.isfinite(heads), axis=1) & np.all(np.isfinite(tails), axis=1)))
    if n_found == 0:
        raise DataError(f"markers ({robot.head_marker} head, {robot.tail_marker} tail) never found in "
                        f"{ts.size} frames from {ts[0] if ts.size else 0:.2f} s to {ts[-1] if ts.size else 0:.2f} s",
                        hint="check the marker colours in trials.toml and the lighting")
    pose = clean_pose(ts, heads, tails, h, p)
    x0, y0, psi0 = pose.at(spec.start_s)
    start_notes = []
    if not np.all(np.isfinite([x0, y0, psi0])):
        # start_s in a gap: take the nearest tracked pose when it is close (the robot starts from rest)
        seen = np.flatnonzero(np.isfinite(pose.x_m) & np.isfinite(pose.heading_rad))
        near = seen[np.argmin(np.abs(pose.t_s[seen] - spec.start_s))] if seen.size else None
        if near is None or abs(pose.t_s[near] - spec.start_s) > p.max_gap_s:
            when = f"nearest tracked pose at {pose.t_s[near]:.2f} s" if near is not None else "never tracked"
            raise DataError(f"markers not found at start_s = {spec.start_s:g} s ({when}), so the trial frame "
                            "is undefined", hint="check the overlay video (glare or an occlusion at the start?)")
        x0, y0, psi0 = float(pose.x_m[near]), float(pose.y_m[near]), float(pose.heading_rad[near])
        start_notes.append(f"markers hidden at start_s; start pose taken from the nearest tracked frame "
                           f"{pose.t_s[near] - spec.start_s:+.2f} s away")
    fitted = start_heading(pose, spec.start_s, p.start_heading_before_s, p.start_heading_after_s)
    if np.isfinite(fitted):
        psi0 = fitted
    if not start_notes:
        # a start at full speed: the smoothed track rounds the kink, take the forward position from a kinked fit
        along = start_position_along(pose, spec.start_s, p.start_heading_before_s, p.start_heading_after_s, psi0)
        if along is not None:
            f = np.array([math.cos(psi0), math.sin(psi0)])
            x0, y0 = np.array([x0, y0]) + (along - (x0 * f[0] + y0 * f[1])) * f
    frame = trial_frame((x0, y0), (math.cos(psi0), math.sin(psi0)))
    after = pose.t_s > spec.start_s
    t_rel = np.concatenate([[0.0], pose.t_s[after] - spec.start_s])
    xy = frame.to_trial(np.column_stack([pose.x_m[after], pose.y_m[after]]))
    x = np.concatenate([[0.0], xy[:, 0]])
    y = np.concatenate([[0.0], xy[:, 1]])
    psi = np.concatenate([[0.0], pose.heading_rad[after] - psi0])
    finite = np.isfinite(x) & np.isfinite(y)
    tracked_until = float(t_rel[finite][-1])
    video_until = info.duration_s - 1.0 / info.fps - spec.start_s
    try:
        score = score_trajectory(spec.task, t_rel, x, y, psi, observed_until_s=tracked_until,
                                 frame_s=1.0 / info.fps, max_gap_s=p.max_gap_s)
    except UndecidedError:
        if video_until >= CAP_S - 1.0 / info.fps:
            raise DataError(f"markers lost {tracked_until:.2f} s after start_s and not found again before the "
                            f"{CAP_S:.0f} s cap, so the trial is undecided",
                            hint="check the overlay video for occlusions or the robot leaving the view") from None
        raise DataError(f"the video ends {video_until:.2f} s after start_s, before the robot finished and "
                            f"before the {CAP_S:.0f} s cap, so the trial cannot be scored",
                        hint="record until the robot finishes or 60 s after start_s") from None
    if start_notes:
        from dataclasses import replace

        score = replace(score, notes=tuple(start_notes) + score.notes)
    return score, frame, pose


def _finish_overlay(writer, spec: TrialSpec, score: TrialScore, frame: TrialFrame, pose: PoseSeries,
                    h: np.ndarray) -> Path:
    h_inv = np.linalg.inv(h)
    path_px = apply_homography(h_inv, np.column_stack([pose.x_m, pose.y_m]))
    extra = [apply_homography(h_inv, frame.to_tank(np.array([[0.0, 0.0], [0.0, 0.5]]))),
             apply_homography(h_inv, frame.to_tank(np.array([[0.0, 0.0], [0.3, 0.0]])))]
    lines = [f"{spec.id}: {spec.model} solution {spec.solution}, {spec.task}"]
    done = "completed" if score.completed else "NOT completed (60 s cap)"
    lines.append(f"time_s = {score.time_s:.2f} s  ({done})")
    if spec.task == "straight":
        for k in range(int(round(STRAIGHT_DISTANCE_M / STATION_STEP_M)) + 1):
            yk = k * STATION_STEP_M
            extra.append(apply_homography(h_inv, frame.to_tank(np.array([[-0.3, yk], [0.3, yk]]))))
        lines.append(f"mae_x_m = {score.mae_x_m:.3f} m over {len(score.stations)} stations")
    elif score.circle_center is None:
        lines.append("radius_m: none (the path is straight)")
    else:
        cx, cy = score.circle_center
        a = np.linspace(0, 2 * np.pi, 73)
        circ = np.column_stack([cx + score.radius_m * np.cos(a), cy + score.radius_m * np.sin(a)])
        extra.append(apply_homography(h_inv, frame.to_tank(circ)))
        lines.append(f"radius_m = {score.radius_m:.3f} m")
    lines.append(f"detected {100 * np.mean(pose.detected):.0f}% of frames, filled {100 * np.mean(pose.filled):.0f}%")
    lines.extend(score.notes)
    return writer.finish(lines, path_px=path_px, extra_px=extra)
