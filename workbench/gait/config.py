"""The optimisation settings: one frozen tree read from ``pipelines/gait.yaml`` (section ``optimize``).

Every constant of the problem (bounds, finish distance, caps, targets, weights, hypervolume
reference points), of the algorithm, the simulator, the tabulation and the outputs lives in the
file. The tree is built by :func:`workbench.params.build`: an unknown key, a wrong type or a
failed check is a :class:`~workbench.errors.ParamsError` naming the file, the key path
(``optimize.tasks.turn.cap_s``) and the allowed keys, so a typo is an error, not a silently
ignored knob. ``OptimizeConfig`` is the name before issue 17 (an alias of :class:`OptimizeSettings`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Mapping

from workbench.errors import ContractError, ParamsError, SettingError
from workbench.gait.objectives import TASKS, TaskSpec
from workbench.gait.problem import SimSettings
from workbench.gait.run import NSGA2Settings
from workbench.gait.space import GaitSpace
from workbench.gait.tabulate import TabulationSettings
from workbench.threads import AUTO, check_setting


def check_workers(value) -> int | str:
    """Validate a ``workers`` setting: a positive integer or ``auto`` (the cores idle at the start)."""
    if value == AUTO:
        return value
    if isinstance(value, bool) or not isinstance(value, (int, str)) or not str(value).isdigit() or int(value) < 1:
        raise SettingError(f"workers must be a positive integer or 'auto', not {value!r}")
    return int(value)


@dataclass(frozen=True)
class TaskSettings:
    """A task's spec and the fixed hypervolume reference point of its objectives."""

    spec: TaskSpec
    hv_reference: tuple[float, float, float]


@dataclass(frozen=True)
class ControllerSettings:
    """The controller gait file: the tabulated cycle's sample rate (Hz)."""

    sample_rate_hz: float = 65.0


@dataclass(frozen=True)
class TrackingSettings:
    """MLflow: on/off, store (None: the project's) and experiment."""

    enabled: bool = True
    tracking_uri: str | None = None
    experiment: str = "optimize"


@dataclass(frozen=True)
class OptimizeSettings:
    """Everything ``workbench optimize`` needs besides the task and the model (``optimize`` section)."""

    robot: str = "pipelines/robot.yaml"
    drag_json: str | None = None
    retain: int = 8
    #: tabulated runs: the best this many are swum again with the direct rollout and re-ranked
    verify_direct: int = 16
    torch_threads: int | str | None = "auto"
    #: simulator worker processes: each swims its share of a population (results identical to one
    #: worker); ``auto``: the cores idle at the start (workbench/threads.py), 1: in this process
    workers: int | str = 1
    space: GaitSpace = GaitSpace()
    #: S = w1 f1 + w2 f2 + w3 f3 for every task that does not give its own
    weights: tuple[float, float, float] = (1.0, 4.0, 2.0)
    #: built by :func:`config_from_dict` (a task's keys, its weights by default the ones above)
    tasks: Mapping[str, TaskSettings] | None = None
    nsga2: NSGA2Settings = NSGA2Settings()
    simulation: SimSettings = SimSettings()
    tabulation: TabulationSettings = TabulationSettings()
    controller: ControllerSettings = ControllerSettings()
    tracking: TrackingSettings = TrackingSettings()

    def __post_init__(self):
        try:
            check_setting(self.torch_threads)
        except SettingError as exc:
            raise SettingError(exc.fault, where="optimize.torch_threads") from None
        try:
            object.__setattr__(self, "workers", check_workers(self.workers))
        except SettingError as exc:
            raise SettingError(exc.fault, where="optimize.workers") from None
        if self.retain < 1 or self.verify_direct < 0:
            raise SettingError("retain must be at least 1 and verify_direct non-negative", where="optimize")

    def task(self, name: str) -> TaskSettings:
        """The settings of one task."""
        if not self.tasks or name not in self.tasks:
            raise ContractError(f"no settings for task {name!r}", hint=f"tasks: {sorted(self.tasks or {})}")
        return self.tasks[name]

    def with_overrides(self, **kw) -> "OptimizeSettings":
        """A copy with NSGA-II settings replaced (``pop_size``, ``n_gen``, ``seed``; None keeps the file's)."""
        changes = {k: v for k, v in kw.items() if v is not None}
        return replace(self, nsga2=replace(self.nsga2, **changes)) if changes else self

    def with_workers(self, workers) -> "OptimizeSettings":
        """A copy with another ``workers`` setting (None keeps the file's); a bad value raises ValueError."""
        return self if workers is None else replace(self, workers=check_workers(workers))

    def record(self) -> dict:
        """JSON-friendly record (for result files and MLflow params); the tasks carry their weights."""
        d = asdict(self)
        d.pop("weights")
        d["tasks"] = {k: {"spec": asdict(v.spec), "hv_reference": list(v.hv_reference)}
                      for k, v in (self.tasks or {}).items()}
        return d


#: the name before issue 17 (settings classes end in ``Settings``); kept for existing imports
OptimizeConfig = OptimizeSettings


@dataclass(frozen=True)
class _Reference:
    hv_reference: tuple[float, float, float]


def config_from_dict(doc: Mapping[str, Any] | None, path: str | Path | None = None, *,
                     key: str = "optimize") -> OptimizeSettings:
    """Build the settings from the ``optimize`` section (``path``: the file, named in every error).

    :func:`workbench.params.build` builds the tree; each task of ``tasks`` is a
    :class:`~workbench.gait.objectives.TaskSpec` (its ``weights`` by default the section's) plus
    the fixed hypervolume reference point ``hv_reference`` (required).
    """
    from workbench.params import build, suggest

    doc = dict(doc or {})
    raw_tasks = doc.pop("tasks", None)
    settings = build(OptimizeSettings, doc, key=key, path=path)
    if raw_tasks is not None and not isinstance(raw_tasks, Mapping):
        raise ParamsError("must be a mapping of tasks", path=path, where=f"{key}.tasks", hint=f"tasks: {TASKS}")
    tasks = {}
    for name, tdoc in (raw_tasks or {}).items():
        where = f"{key}.tasks.{name}"
        if name not in TASKS:
            raise ParamsError(f"unknown task '{name}'", path=path, where=where, hint=suggest(str(name), TASKS))
        if not isinstance(tdoc, Mapping) or "hv_reference" not in tdoc:
            raise ParamsError("hv_reference is required (a fixed point [f1, f2, f3])", path=path, where=where)
        tdoc = dict(tdoc)
        ref = build(_Reference, {"hv_reference": tdoc.pop("hv_reference")}, key=where, path=path).hv_reference
        spec = TaskSpec.from_dict(name, tdoc, settings.weights, key=where, path=path)
        tasks[name] = TaskSettings(spec, ref)
    return replace(settings, tasks=tasks)


def load_config(path: str | Path = "pipelines/gait.yaml", section: str = "optimize") -> OptimizeSettings:
    """Read the optimisation settings from a pipeline parameter file."""
    from workbench.params import read_section

    raw, source = read_section(path, section)
    return config_from_dict(raw, source, key=section)
