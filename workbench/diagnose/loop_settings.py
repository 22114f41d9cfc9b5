"""The diagnosis's settings: every knob of ``pipelines/diagnose.yaml`` as frozen dataclasses.

:class:`DiagnoseSettings` nests the blocks of the data, fit, selection, evidence, library and
report sections and builds itself from the YAML section through ``workbench.params``
(unknown keys and wrong types are a ParamsError naming the key path).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from workbench.diagnose.data import DataSettings
from workbench.diagnose.evidence_base import EvidenceSettings
from workbench.diagnose.problem import FitSettings
from workbench.diagnose.selection import SelectionSettings


@dataclass(frozen=True)
class LibrarySettings:
    """Which effects are candidates and their fixed options (section ``library``)."""

    #: effect names (empty: the whole documented library)
    effects: tuple[str, ...] = ()
    #: lateral offset of thigh and calf from the hip axis (m) and Gauss points per link
    link_x_m: float = 0.01
    link_quadrature: int = 4
    #: drag coefficient of the force that passes the circulatory lag (null: the EF's own C_R)
    circulatory_c_r: float | None = None
    #: constructor options per effect, ``{effect: {option: value}}`` (an effect's own knobs, e.g.
    #: ``wagner_lag: {time_scale: 1.2}``); they win over the shared keys above
    options: dict = field(default_factory=dict)


@dataclass(frozen=True)
class ReportSettings:
    """What counts as unexplained, and report details (section ``report``)."""

    #: a gait-locked misfit is reported when, beyond noise, it holds at least this share of a channel's residual
    locked_min_share: float = 0.2
    #: a channel's effect contribution is listed when it removes at least this share of its error
    channel_min_gain: float = 0.02
    example_runs: int = 3


@dataclass(frozen=True)
class DiagnoseSettings:
    """Every knob of the diagnosis (``pipelines/diagnose.yaml``)."""

    data: DataSettings = field(default_factory=DataSettings)
    fit: FitSettings = field(default_factory=FitSettings)
    selection: SelectionSettings = field(default_factory=SelectionSettings)
    evidence: EvidenceSettings = field(default_factory=EvidenceSettings)
    library: LibrarySettings = field(default_factory=LibrarySettings)
    report: ReportSettings = field(default_factory=ReportSettings)
    #: match the ingest's zero-phase low-pass on the predictions (null: from the processed file)
    lowpass_cutoff_hz: float | None = None
    lowpass_order: int | None = None
    match_lowpass: bool = True

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any] | None, path: str | None = None) -> "DiagnoseSettings":
        """Build from the YAML section of file ``path`` (workbench.params).

        Unknown keys and wrong types are a ParamsError naming the key path (``diagnose.fit.surrogate_serch``).
        """
        from workbench.params import build

        values = dict(values or {})
        # the trajectory level reads its own section (workbench.diagnose.trajectory.TrajectorySettings)
        values.pop("trajectory", None)
        return build(cls, values, key="diagnose", path=path)
