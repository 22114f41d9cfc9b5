"""The optimisation settings: one frozen tree read from ``pipelines/gait.yaml`` (section ``optimize``).

Every constant of the problem (bounds, finish distance, caps, targets, weights, hypervolume
reference points), of the algorithm, the simulator, the tabulation and the outputs lives in the
file; unknown keys are refused so a typo is an error, not a silently ignored knob.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Mapping

from workbench.errors import ContractError
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
        raise ValueError(f"workers must be a positive integer or 'auto', not {value!r}")
    return int(value)

_TOP_KEYS = ("robot", "drag_json", "retain", "verify_direct", "torch_threads", "workers", "space", "weights", "tasks",
             "nsga2", "simulation", "tabulation", "controller", "tracking")


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
class OptimizeConfig:
    """Everything ``workbench optimize`` needs besides the task and the model."""

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
    tasks: Mapping[str, TaskSettings] | None = None
    nsga2: NSGA2Settings = NSGA2Settings()
    simulation: SimSettings = SimSettings()
    tabulation: TabulationSettings = TabulationSettings()
    controller: ControllerSettings = ControllerSettings()
    tracking: TrackingSettings = TrackingSettings()

    def task(self, name: str) -> TaskSettings:
        """The settings of one task."""
        if not self.tasks or name not in self.tasks:
            raise ContractError(f"no settings for task {name!r}", hint=f"tasks: {sorted(self.tasks or {})}")
        return self.tasks[name]

    def with_overrides(self, **kw) -> "OptimizeConfig":
        """A copy with NSGA-II settings replaced (``pop_size``, ``n_gen``, ``seed``; None keeps the file's)."""
        changes = {k: v for k, v in kw.items() if v is not None}
        return replace(self, nsga2=replace(self.nsga2, **changes)) if changes else self

    def with_workers(self, workers) -> "OptimizeConfig":
        """A copy with another ``workers`` setting (None keeps the file's); a bad value raises ValueError."""
        return self if workers is None else replace(self, workers=check_workers(workers))

    def record(self) -> dict:
        """JSON-friendly record (for result files and MLflow params)."""
        d = asdict(self)
        d["tasks"] = {k: {"spec": asdict(v.spec), "hv_reference": list(v.hv_reference)}
                      for k, v in (self.tasks or {}).items()}
        return d


def config_from_dict(doc: Mapping[str, Any], path: str | Path = "gait parameters") -> OptimizeConfig:
    """Build the config from the ``optimize`` section; a bad value is a one-line ContractError naming the file."""
    doc = dict(doc or {})
    unknown = sorted(set(doc) - set(_TOP_KEYS))
    if unknown:
        raise ContractError(f"unknown key(s) {unknown} in section 'optimize'", path=path, hint=f"known: {_TOP_KEYS}")
    try:
        weights = tuple(float(w) for w in doc.get("weights", (1.0, 4.0, 2.0)))
        tasks = {}
        for name, tdoc in dict(doc.get("tasks") or {}).items():
            if name not in TASKS:
                raise ValueError(f"unknown task {name!r} (known: {TASKS})")
            tdoc = dict(tdoc or {})
            ref = tdoc.pop("hv_reference", None)
            spec = TaskSpec.from_dict(name, tdoc, weights=weights)
            if ref is None:
                raise ValueError(f"tasks.{name}.hv_reference is required (a fixed point [f1, f2, f3])")
            ref = tuple(float(r) for r in ref)
            if len(ref) != 3:
                raise ValueError(f"tasks.{name}.hv_reference needs three numbers")
            tasks[name] = TaskSettings(spec, ref)
        controller = ControllerSettings(**dict(doc.get("controller") or {}))
        tracking = TrackingSettings(**dict(doc.get("tracking") or {}))
        threads = check_setting(doc.get("torch_threads", "auto"))
        workers = check_workers(doc.get("workers", 1))
        retain = int(doc.get("retain", 8))
        verify = int(doc.get("verify_direct", 16))
        if retain < 1 or verify < 0:
            raise ValueError("retain must be at least 1 and verify_direct non-negative")
        return OptimizeConfig(
            robot=str(doc.get("robot", "pipelines/robot.yaml")), drag_json=doc.get("drag_json"), retain=retain,
            verify_direct=verify,
            torch_threads=threads, workers=workers, space=GaitSpace.from_dict(doc.get("space")),
            tasks=tasks, nsga2=NSGA2Settings.from_dict(doc.get("nsga2"), str(path)),
            simulation=SimSettings.from_dict(doc.get("simulation")),
            tabulation=TabulationSettings.from_dict(doc.get("tabulation")), controller=controller, tracking=tracking)
    except (ValueError, TypeError) as exc:
        raise ContractError(str(exc), path=path) from None


def load_config(path: str | Path = "pipelines/gait.yaml", section: str = "optimize") -> OptimizeConfig:
    """Read the optimisation settings from a pipeline parameter file."""
    from workbench.project import load_params

    return config_from_dict(load_params(path, section), path)
