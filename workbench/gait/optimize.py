"""One optimisation from settings to results in memory: problem, NSGA-II, ranking, re-simulation, documents.

:func:`optimize_task` is what ``workbench optimize``, the tests and the benchmark call; it touches
no files. The retained gaits are simulated once more on their own: the trajectories feed the
plot. For a model served from tables (the FED-LSTM) that second swim is the direct rollout of the
best ``verify_direct`` candidates, which are re-ranked by it, so the recorded objectives are the
model's own; otherwise the largest relative change of the objectives (``resim_max_rel_diff``)
shows that recorded objectives are reproducible from the gait file alone.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

from workbench.gait.config import OptimizeSettings
from workbench.gait.export import best_table, controller_document, gait_document
from workbench.gait.objectives import score
from workbench.gait.problem import GaitProblem
from workbench.gait.run import Generation, OptimizeResult, hypervolume, non_dominated, run_nsga2
from workbench.hydro.legmodel import LegForceModel
from workbench.hydro.robot import RobotSettings
from workbench.hydro.simulator import Trajectory


@dataclass
class GaitOutcome:
    """Everything an optimisation produced, ready to be written."""

    task: str
    model: str
    result: OptimizeResult
    retained: OptimizeResult
    trajectories: Trajectory
    gait_doc: dict
    controller_doc: dict
    table: list[dict]
    metrics: dict
    pngs: dict[str, bytes] = field(default_factory=dict)


def relative_difference(a: np.ndarray, b: np.ndarray, floor: float = 1e-9) -> float:
    """Largest |a - b| / max(|b|, floor) over all entries."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.size == 0:
        return 0.0
    return float((np.abs(a - b) / np.maximum(np.abs(b), floor)).max())


#: floors of the relative differences reported for tabulated vs direct objectives (docs/gaits.md)
FLOORS = {"straight": (0.05, 0.05, 1.0), "turn": (0.1, 0.05, 1.0)}


def objective_differences(f: np.ndarray, f_ref: np.ndarray, task: str) -> list[float]:
    """Per objective, the largest |f - f_ref| / max(|f_ref|, floor) (floors: 0.05 N s or 0.1 m, 0.05 rad, 1 s)."""
    floor = np.asarray(FLOORS[task])
    return [float(v) for v in (np.abs(f - f_ref) / np.maximum(np.abs(f_ref), floor)).max(axis=0)]


def verify_direct(problem: GaitProblem, result: OptimizeResult, k: int) -> tuple[OptimizeResult, Trajectory, dict]:
    """Swim the best ``k`` of a tabulated run with the direct rollout and re-rank them by the direct S.

    The search ran on tabulated wrenches; what is recorded and kept is the model's own answer.
    Returns the re-ranked candidates (direct objectives), their trajectories and the differences.
    """
    from dataclasses import replace

    direct = GaitProblem(problem.spec, problem.leg_model, problem.robot, space=problem.space, sim=problem.sim,
                         tabulation=replace(problem.tabulation, mode="never"))
    direct.workers = problem.workers  # the same worker processes swim the direct rollouts
    x = result.x[:k]
    gaits = problem.space.gaits(x)
    # the tabulated swims' flow is within about a percent of the direct one: the direct fixed point starts there
    start = problem.simulate(gaits).leg_flow_mps
    f_dir, traj = direct.evaluate_gaits(gaits, initial_flow=start)
    s_dir = score(f_dir, problem.spec.weights)
    ok = traj.converged
    order = np.lexsort((s_dir, ~ok))
    problem.log.unconverged += direct.log.unconverged
    info = {"verified_direct": int(k), "verify_seconds": direct.log.seconds,
            "verify_unconverged": int(direct.log.unconverged),
            "verify_max_rel_diff": objective_differences(result.f[:k], f_dir, problem.spec.task),
            "verify_max_rel_diff_score": relative_difference(result.s[:k], s_dir)}
    ranked = OptimizeResult(x[order], f_dir[order], s_dir[order], result.history, result.evaluations,
                            result.seconds, result.method, ok[order])
    return ranked, _rows(traj, order), info


def _rows(traj: Trajectory, order: np.ndarray) -> Trajectory:
    """The trajectories of some gaits, in the given order."""
    from dataclasses import replace

    fields = ("x_m", "y_m", "yaw_rad", "vx_mps", "vy_mps", "yaw_rate_rps", "leg_wrench", "body_wrench",
              "leg_flow_mps", "residual_mps", "converged")
    return replace(traj, gaits=traj.gaits.rows(order), **{k: getattr(traj, k)[order] for k in fields})


def _converged_only(retained: OptimizeResult, traj: Trajectory, task: str,
                    model_label: str) -> tuple[OptimizeResult, Trajectory, int]:
    """The retained gaits whose simulations converged (and their trajectories), and how many were dropped.

    A gait whose fixed point did not converge has no trustworthy objectives or path: it never
    reaches the gait file, the controller file or a figure. None converged is a ConvergenceError.
    """
    from workbench.errors import ConvergenceError

    ok = np.asarray(retained.converged, bool)
    if not ok.any():
        raise ConvergenceError(f"none of the {len(ok)} best {task} gaits' simulations with model '{model_label}' "
                               "converged: there is no gait to keep",
                               hint="see the unconverged count per generation; docs/hydro.md (simulation settings)")
    if ok.all():
        return retained, traj, 0
    keep = np.flatnonzero(ok)
    kept = OptimizeResult(retained.x[keep], retained.f[keep], retained.s[keep], retained.history,
                          retained.evaluations, retained.seconds, retained.method, ok[keep])
    return kept, _rows(traj, keep), int((~ok).sum())


def optimize_task(cfg: OptimizeSettings, task: str, leg_model: LegForceModel, robot: RobotSettings, *,
                  model_label: str, model_spec: str | None = None,
                  on_generation: Callable[[Generation], None] | None = None, plots: bool = True,
                  workers: int | None = None) -> GaitOutcome:
    """Run NSGA-II on one task with one leg model and assemble the outcome.

    With tabulated leg wrenches the best ``cfg.verify_direct`` of the final population are swum
    again with the direct rollout, re-ranked by the direct S, and the best ``cfg.retain`` of them
    kept with their direct objectives; otherwise the best ``retain`` are re-simulated as they were
    found, and ``resim_max_rel_diff`` shows that their recorded objectives come back.

    ``workers`` processes (None: ``cfg.workers`` resolved now) swim the parts of every batch
    (:mod:`workbench.gait.workers`); the number is recorded, the results do not depend on it.
    """
    from workbench.gait.workers import resolve_workers, sim_workers

    ts = cfg.task(task)
    problem = GaitProblem(ts.spec, leg_model, robot, space=cfg.space, sim=cfg.simulation, tabulation=cfg.tabulation)
    n_workers = resolve_workers(cfg.workers if workers is None else workers)
    t0 = time.perf_counter()
    with sim_workers(problem, n_workers) as pool:
        problem.workers = pool
        try:
            outcome = _search(cfg, ts, task, problem, robot, model_label, model_spec, on_generation, plots, t0)
        finally:
            problem.workers = None
    outcome.metrics["workers"] = n_workers
    if pool is not None:  # the workers' CPU, all and on the critical path (docs/gaits.md "Workers")
        outcome.metrics["workers_cpu_s"] = pool.cpu_s
        outcome.metrics["workers_busiest_cpu_s"] = pool.busiest_cpu_s
    outcome.gait_doc["workers"] = n_workers
    return outcome


def _search(cfg: OptimizeSettings, ts, task: str, problem: GaitProblem, robot: RobotSettings, model_label: str,
            model_spec: str | None, on_generation, plots: bool, t0: float) -> GaitOutcome:
    """NSGA-II, the direct check or re-simulation, and the documents (see :func:`optimize_task`)."""
    leg_model = problem.leg_model
    result = run_nsga2(problem, cfg.nsga2, ts.hv_reference, on_generation=on_generation)
    verify: dict = {}
    if problem.log.table and cfg.verify_direct > 0:
        ranked, traj, verify = verify_direct(problem, result, min(max(cfg.verify_direct, cfg.retain), len(result.s)))
        retained = ranked.best(cfg.retain)
        traj = _rows(traj, np.arange(len(retained.s)))
        resim = None
    else:
        retained = result.best(cfg.retain)
        f_again, traj = problem.evaluate_gaits(problem.space.gaits(retained.x))
        resim = relative_difference(f_again, retained.f)
        retained.converged = retained.converged & traj.converged
    retained, traj, dropped = _converged_only(retained, traj, task, model_label)
    gaits = problem.space.gaits(retained.x)
    seconds = time.perf_counter() - t0
    log = problem.log
    extra = {"seed": cfg.nsga2.seed, "model_spec": model_spec or model_label,
             "model_description": leg_model.describe(), "settings": problem.describe() | {"nsga2": asdict(cfg.nsga2)},
             "evaluations": result.evaluations,
             # simulations that did not converge (penalised: ranked below every converged gait), checks included
             "unconverged_gaits": int(log.unconverged), "simulated_gaits": int(log.gaits)}
    gait_doc = gait_document(ts.spec, model_label, gaits, retained.f, retained.s, extra=extra,
                             converged=retained.converged, gait_space=cfg.space.extension)
    ctrl = controller_document(ts.spec, model_label, gaits, retained.s, sample_rate_hz=cfg.controller.sample_rate_hz,
                               haa_deg=robot.haa_angle_deg, gait_space=cfg.space.extension)
    feasible = result.f[result.converged]
    front = feasible[non_dominated(feasible)]
    metrics = {
        "task": task, "model": model_label, "best_score": float(retained.s[0]),
        "best_f1": float(retained.f[0, 0]), "best_f2": float(retained.f[0, 1]), "best_f3": float(retained.f[0, 2]),
        "hypervolume": hypervolume(front, np.asarray(ts.hv_reference)), "front_size": int(len(front)),
        "evaluations": int(result.evaluations), "generations": len(result.history), "seconds": seconds,
        "simulation_seconds": log.seconds, "unconverged_gaits": int(log.unconverged), "simulated_gaits": int(log.gaits),
        "retained_unconverged": int((~retained.converged).sum()), "dropped_unconverged": dropped,
        "resim_max_rel_diff": resim, "tabulation": dict(log.table), **verify,
    }
    outcome = GaitOutcome(task, model_label, result, retained, traj, gait_doc, ctrl,
                          best_table(ts.spec, gaits, retained.f, retained.s), metrics)
    if plots:
        from workbench.gait.plots import history_png, pareto_png, trajectories_png

        title = f"{task} - {model_label}"
        ok = result.converged  # unconverged gaits have no trustworthy objectives: not drawn (counted in the title)
        left_out = f" ({int((~ok).sum())} unconverged not drawn)" if not ok.all() else ""
        outcome.pngs = {"pareto.png": pareto_png(result.f[ok], min(len(retained.s), int(ok.sum())), ts.spec,
                                                 f"final population: {title}{left_out}"),
                        "hypervolume.png": history_png(result.history, f"NSGA-II: {title}"),
                        "trajectories.png": trajectories_png(traj, ts.spec, f"best {len(retained.s)}: {title}")}
    return outcome
