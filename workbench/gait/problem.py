"""The gait optimisation problem as a pymoo ``Problem``: a whole population per simulator call.

``GaitProblem._evaluate`` maps the population's decision vectors (paper Table II) to a
:class:`GaitBatch`, swims all of it in one :func:`simulate` call (leg wrenches tabulated per
gait shape when the model has memory, :mod:`workbench.gait.tabulate`) and writes the (pop, 3)
objectives of the task (paper Table III) to ``out["F"]``. The same object serves ``minimize``,
an ask/tell loop (e.g. with pool trials in the loop) and re-simulation of retained gaits.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Literal, Mapping

import numpy as np
from pymoo.core.problem import Problem

from workbench.gait.objectives import TaskSpec, objectives
from workbench.gait.space import GaitSpace
from workbench.gait.tabulate import TabulatedLegModel, TabulationSettings
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.robot import RobotSettings
from workbench.hydro.simulator import DEFAULT_DT_S, GaitBatch, Trajectory, simulate


@dataclass(frozen=True)
class SimSettings:
    """Simulator settings other than the duration (which is the task's cap)."""

    dt_s: float = DEFAULT_DT_S
    tol_mps: float = 1e-5
    max_iter: int = 40
    relaxation: float = 1.0
    method: Literal["windowed", "picard"] = "windowed"
    window_s: float = 20.0
    max_window_s: float = 60.0
    anderson: int = 5

    def kwargs(self) -> dict:
        """Keyword arguments of :func:`simulate` (all but the duration)."""
        from dataclasses import asdict

        return asdict(self)


@dataclass
class EvaluationLog:
    """Running totals of the evaluations: gaits, simulator calls, seconds, unconverged gaits, table work."""

    gaits: int = 0
    calls: int = 0
    seconds: float = 0.0
    unconverged: int = 0
    table: dict = field(default_factory=dict)

    def add_table(self, stats: Mapping[str, Any]) -> None:
        """Accumulate a tabulated model's work counters."""
        for k, v in stats.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool) and k != "shapes":
                self.table[k] = self.table.get(k, 0) + v
            elif k == "kind":
                self.table[k] = v


class GaitProblem(Problem):
    """Minimise the task's three objectives over gait parameters; one simulation per population.

    A gait whose simulation did not converge has no trustworthy objectives: it gets one inequality
    constraint violated, g = residual / tol - 1 > 0 (pymoo's constraint domination ranks every
    converged gait above it, and less unconverged above more), and it is counted
    (``log.unconverged``; the gait file and the MLflow run carry the count).
    """

    def __init__(self, spec: TaskSpec, leg_model: LegForceModel, robot: RobotSettings, *,
                 space: GaitSpace | None = None, sim: SimSettings | None = None,
                 tabulation: TabulationSettings | None = None):
        self.spec = spec
        self.leg_model = leg_model
        self.robot = robot
        self.space = space or GaitSpace()
        self.sim = sim or SimSettings()
        self.tabulation = tabulation or TabulationSettings()
        self.log = EvaluationLog()
        self._flow_kernel: np.ndarray | None = None
        #: worker processes that swim parts of each batch (workbench.gait.workers; None: this process)
        self.workers = None
        super().__init__(n_var=len(self.space.variables), n_obj=3, n_ieq_constr=1, xl=self.space.xl, xu=self.space.xu,
                         vtype=float)

    # -- pymoo -----------------------------------------------------------------------------------
    def _evaluate(self, x, out, *args, **kwargs):
        f, residual, converged = self.objectives_of(self.space.gaits(x))
        # an unconverged gait's objectives mean nothing; keep them finite for the sorting (the constraint ranks it)
        out["F"] = np.where(np.isfinite(f), f, 1e6)
        out["G"] = self.violation(residual, converged)[:, None]

    def violation(self, residual_mps: np.ndarray, converged: np.ndarray) -> np.ndarray:
        """(B,) constraint values: <= 0 for a converged simulation, residual / tol - 1 (capped) otherwise."""
        g = np.minimum(np.nan_to_num(residual_mps, nan=np.inf) / self.sim.tol_mps - 1.0, 1e6)
        return np.where(converged, np.minimum(g, 0.0), np.maximum(g, 1e-6))

    # -- direct use ------------------------------------------------------------------------------
    def model_for(self, gaits: GaitBatch) -> LegForceModel:
        """The leg model the simulator gets for this batch: tabulated (bound to it) or the model itself."""
        if self.tabulation.mode == "never":
            return self.leg_model
        wrapped = TabulatedLegModel(self.leg_model, gaits, self.tabulation, sim_dt_s=self.sim.dt_s,
                                    flow_kernel=self._flow_kernel)
        if not wrapped.tabulating:
            return self.leg_model
        if self._flow_kernel is None:
            self._flow_kernel = wrapped.flow_kernel  # probe the model once per problem
        return wrapped

    def simulate(self, gaits: GaitBatch, initial_flow: np.ndarray | None = None) -> Trajectory:
        """Swim the batch for the task's cap (one simulator call), counting the work."""
        if self.workers is not None and len(gaits) > 1:
            return self._in_workers(gaits, initial_flow, full=True)["traj"]
        t0 = time.perf_counter()
        model = self.model_for(gaits)
        traj = simulate(gaits, model, self.robot, duration_s=self.spec.cap_s, initial_flow=initial_flow,
                        **self.sim.kwargs())
        self.log.gaits += len(gaits)
        self.log.calls += 1
        self.log.seconds += time.perf_counter() - t0
        self.log.unconverged += int((~traj.converged).sum())
        if isinstance(model, TabulatedLegModel):
            self.log.add_table(model.stats())
        return traj

    def _in_workers(self, gaits: GaitBatch, initial_flow: np.ndarray | None, full: bool) -> dict:
        """Swim the batch in the worker processes, counting the work as :meth:`simulate` does."""
        t0 = time.perf_counter()
        r = self.workers.swim(gaits, initial_flow, self.tabulation.mode, full)
        self.log.gaits += len(gaits)
        self.log.calls += 1
        self.log.seconds += time.perf_counter() - t0
        self.log.unconverged += int(r["unconverged"])
        for table in r["tables"]:
            if table:
                self.log.add_table(table)
        return r

    def objectives_of(self, gaits: GaitBatch) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(B, 3) objectives, (B,) residuals and convergence of a batch (in the workers when there are any)."""
        if self.workers is not None and len(gaits) > 1:
            r = self._in_workers(gaits, None, full=False)
            return r["f"], r["residual"], r["converged"]
        traj = self.simulate(gaits)
        return objectives(traj, self.spec), traj.residual_mps, traj.converged

    def evaluate_gaits(self, gaits: GaitBatch, initial_flow: np.ndarray | None = None) -> tuple[np.ndarray, Trajectory]:
        """(B, 3) objectives and the trajectories of a gait batch (``initial_flow``: a first guess, see simulate)."""
        traj = self.simulate(gaits, initial_flow)
        return objectives(traj, self.spec), traj

    def describe(self) -> dict:
        """Settings worth recording with results."""
        from dataclasses import asdict

        return {"task": asdict(self.spec), "space": asdict(self.space), "simulation": asdict(self.sim),
                "tabulation": asdict(self.tabulation), "model": self.leg_model.describe()}
