"""Scoring knobs (``scoring`` section of pipelines/trials.yaml) as one frozen dataclass.

The contract fixes the scores themselves (2 m, 0.25 m stations, 360 degrees, 60 s cap); these
are the knobs of detection, tracking and output, with the defaults the docs justify.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any, Mapping

from workbench.errors import ContractError


@dataclass(frozen=True)
class ScoringParams:
    """Detection, tracking and output settings for ``workbench score-trials``."""

    # --- detection (HSV gates; hue half-width in OpenCV units, 1 unit = 2 degrees)
    hue_halfwidth: int = 14
    sat_min: int = 90
    #: laxer saturation gate tried only near a confident prediction (markers washed out by glare)
    sat_min_relaxed: int = 45
    val_min: int = 50
    #: full-frame search (acquisition) runs on a frame shrunk by this factor
    downscale: int = 2
    marker_diameter_min_m: float = 0.02
    marker_diameter_max_m: float = 0.25
    # --- tracking
    spacing_min_m: float = 0.05
    spacing_max_m: float = 0.8
    #: accepted relative change of the head-tail spacing against its running median
    spacing_tolerance: float = 0.3
    #: speed gate for a marker between accepted detections (robot swims at ~0.1 m/s)
    max_speed_mps: float = 1.0
    #: search window around each predicted marker position
    roi_margin_m: float = 0.12
    #: while the markers are lost, search the whole frame this often
    search_every_s: float = 0.2
    # --- cleaning
    #: gaps up to this long are filled (shape-preserving cubic); longer ones stay gaps
    max_gap_s: float = 1.5
    hampel_window_s: float = 1.0
    hampel_sigmas: float = 4.0
    hampel_floor_m: float = 0.02
    hampel_floor_deg: float = 4.0
    #: Savitzky-Golay smoothing of position and heading (window, polynomial order)
    smooth_window_s: float = 0.5
    smooth_order: int = 2
    #: heading is noisier than position (two markers a few pixels apart): a longer window
    heading_window_s: float = 1.0
    #: the heading at start_s is a quadratic fit to the heading over [start_s - before, start_s + after]
    start_heading_before_s: float = 1.0
    start_heading_after_s: float = 2.0
    # --- run
    #: frames decoded before start_s to seed the tracker and the start pose
    pre_start_s: float = 1.0
    #: stop decoding once a trial is clearly decided, this long after the decision
    stop_after_decided_s: float = 1.0
    early_stop: bool = True
    workers: int = 2
    # --- outputs
    overlay: bool = True
    #: overlay videos are at most this wide (smaller is cheaper to encode)
    overlay_width_px: int = 480
    plots: bool = True
    #: the model others are compared against (None: "EF" if present, else the first name)
    baseline: str | None = None

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None, *, source: str = "scoring params") -> "ScoringParams":
        """Build from a mapping, refusing unknown keys (a typo must not pass silently)."""
        m = dict(m or {})
        known = {f.name: f for f in fields(cls)}
        unknown = sorted(set(m) - set(known))
        if unknown:
            raise ContractError(f"unknown scoring parameter(s) {', '.join(unknown)}", path=source,
                                hint=f"known: {', '.join(known)}")
        out = {}
        for k, v in m.items():
            default = getattr(cls, k)
            if isinstance(default, bool):
                if not isinstance(v, bool):
                    raise ContractError(f"scoring parameter {k} must be true or false", path=source)
            elif isinstance(default, int) and not isinstance(default, bool):
                if not isinstance(v, int) or isinstance(v, bool):
                    raise ContractError(f"scoring parameter {k} must be an integer", path=source)
            elif isinstance(default, float):
                if not isinstance(v, (int, float)) or isinstance(v, bool):
                    raise ContractError(f"scoring parameter {k} must be a number", path=source)
                v = float(v)
            out[k] = v
        return cls(**out)

    def replace(self, **changes) -> "ScoringParams":
        """A copy with some fields changed (None values are ignored)."""
        from dataclasses import replace

        return replace(self, **{k: v for k, v in changes.items() if v is not None})
