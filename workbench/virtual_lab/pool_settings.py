"""The virtual pool's settings: every knob of the ``pool`` section, the marker paints and the models' names.

Shared by the trajectory source (:mod:`workbench.virtual_lab.pool_trajectories`), the renderer
(:mod:`workbench.virtual_lab.pool_render`) and the folder writer (:mod:`workbench.virtual_lab.pool`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from workbench.contract.trials import MARKER_COLOURS
from workbench.errors import ParamsError

#: BGR paint of each contract colour name (saturated, mid-bright: what a printed marker looks like).
MARKER_BGR = {"red": (40, 40, 205), "green": (60, 165, 35), "blue": (185, 75, 20), "yellow": (40, 195, 215),
              "magenta": (175, 50, 185), "cyan": (195, 185, 35)}
#: the paper's names of the models whose gaits are run (``lstmNN``: the FED-LSTM on NN-tick windows)
DEFAULT_LABELS = {"ef": "EF", "lstm": "FED-LSTM", "lstm16": "FED-LSTM-16"}


def model_display_label(model: str, labels: Mapping[str, str] | None = None) -> str:
    """The name a gait file's model gets in trials.toml and the scores.

    ``labels`` (the ``model_labels`` setting) first, then :data:`DEFAULT_LABELS`, then
    ``lstmNN`` -> ``FED-LSTM-NN`` (the FED-LSTM on NN-tick windows), then ``NAME-sides`` (gaits of
    the per_side_range gait space, pipelines/gait_sides.yaml) -> NAME's label + ``-sides``, else the
    name upper-cased.
    """
    import re

    if labels and model in labels:
        return str(labels[model])
    if model in DEFAULT_LABELS:
        return DEFAULT_LABELS[model]
    if model.endswith("-sides") and len(model) > 6:
        return model_display_label(model[:-6], labels) + "-sides"
    m = re.fullmatch(r"lstm[-_]?(\d+)", model)
    return f"FED-LSTM-{m.group(1)}" if m else model.upper()


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

    def __post_init__(self):
        for key in ("head_marker", "tail_marker"):
            if getattr(self, key) not in MARKER_COLOURS:
                raise ParamsError(f"marker colour {getattr(self, key)!r} is not one of {', '.join(MARKER_COLOURS)}",
                                  where=f"pool.{key}")
        if self.width_px < 64 or self.height_px < 64 or self.fps <= 0:
            raise ParamsError("width_px, height_px must be >= 64 and fps positive", where="pool")

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any] | None, *, source: str | None = None) -> "PoolSettings":
        """Build from the ``pool`` section (workbench.params: unknown keys, wrong types are a ParamsError)."""
        from workbench.params import build

        return build(cls, m, key="pool", path=source)
