"""Ingest parameters: every knob of the pipeline, with the defaults ``pipelines/ingest.yaml`` documents."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Mapping

from workbench.contract.limits import Limits
from workbench.errors import ParamsError


@dataclass(frozen=True)
class IngestSettings:
    """What ingest does to the raw signals; recorded in the processed file's metadata.

    ``workers`` only changes speed, never the result, so it is left out of :meth:`recorded`.
    """

    #: zero-phase low-pass cutoff (Hz): the -3 dB point of the whole forward-backward filter
    lowpass_cutoff_hz: float = 6.0
    #: Butterworth order of one pass (the forward-backward filter doubles the roll-off)
    lowpass_order: int = 4
    #: Savitzky-Golay window (controller ticks, odd) and polynomial order for angular velocities
    velocity_window_ticks: int = 7
    velocity_polyorder: int = 3
    #: a step in a device clock longer than this and than ``gap_factor`` median steps is a gap
    max_gap_s: float = 0.05
    gap_factor: float = 2.5
    #: NaN runs up to this many samples are bridged by linear interpolation (and flagged)
    max_nan_run: int = 2
    #: keep at most this much of the pre-run rest stretch (s before the first trigger edge)
    max_rest_s: float = 5.0
    #: angles may wander this much (deg) during the rest stretch before it counts as not at rest
    rest_tolerance_deg: float = 0.5
    #: largest allowed misfit of a paired trigger edge to the fitted clock line (ms)
    max_edge_residual_ms: float = 3.0
    #: a reading at or above this fraction of [loadcell] full_scale counts as saturated
    saturation_fraction: float = 0.999
    #: worker threads over runs (0: automatic, at most 2); does not change the result
    workers: int = 0
    #: the rig's plausible ranges (workbench.contract.limits); a YAML mapping ``limits: {...}``
    #: overrides single bounds. Not recorded: it decides what is refused, never how data is processed
    limits: Limits = field(default_factory=Limits)

    def __post_init__(self):
        problems = []
        if not 0 < self.lowpass_cutoff_hz:
            problems.append("lowpass_cutoff_hz must be positive")
        if not 1 <= self.lowpass_order <= 10:
            problems.append("lowpass_order must be 1..10")
        if self.velocity_window_ticks < 3 or self.velocity_window_ticks % 2 == 0:
            problems.append("velocity_window_ticks must be odd and at least 3")
        if not 1 <= self.velocity_polyorder < self.velocity_window_ticks:
            problems.append("velocity_polyorder must be at least 1 and below the window")
        if self.max_gap_s <= 0 or self.gap_factor <= 1:
            problems.append("max_gap_s must be positive and gap_factor above 1")
        if self.max_nan_run < 0 or self.max_rest_s < 0 or self.workers < 0:
            problems.append("max_nan_run, max_rest_s and workers must not be negative")
        if problems:
            raise ParamsError("; ".join(problems), where="ingest")
        if not isinstance(self.limits, Limits):
            object.__setattr__(self, "limits", Limits.from_mapping(self.limits))

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | None) -> "IngestSettings":
        """Build from a parameter-file section (workbench.params: unknown keys and wrong types are a ParamsError)."""
        from workbench.params import build

        return build(cls, values, key="ingest")

    def recorded(self) -> dict[str, Any]:
        """The parameters that shape the result (what the file metadata records and compares)."""
        d = asdict(self)
        d.pop("workers")
        d.pop("limits")
        return d


#: the name before issue 17 (settings classes end in ``Settings``); kept for existing imports
IngestParams = IngestSettings
