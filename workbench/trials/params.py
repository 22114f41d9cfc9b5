"""Scoring knobs (``scoring`` section of pipelines/trials.yaml) as one frozen dataclass.

The contract fixes the scores themselves (2 m, 0.25 m stations, 360 degrees, 60 s cap); these
are the knobs of detection, tracking and output, with the defaults the docs justify.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping


@dataclass(frozen=True)
class ScoringSettings:
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
    def from_mapping(cls, m: Mapping[str, Any] | None, *, source: str = "scoring params") -> "ScoringSettings":
        """Build from the ``scoring`` section (workbench.params: unknown keys and wrong types are a ParamsError)."""
        from workbench.params import build

        return build(cls, m, key="scoring", path=None if source == "scoring params" else source)

    def replace(self, **changes) -> "ScoringSettings":
        """A copy with some fields changed (None values are ignored)."""
        from dataclasses import replace

        return replace(self, **{k: v for k, v in changes.items() if v is not None})


#: the name before issue 17 (settings classes end in ``Settings``); kept for existing imports
ScoringParams = ScoringSettings
