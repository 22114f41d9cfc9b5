"""Simulator worker processes: a gait batch's swims split across cores, the results those of one process.

The simulator solves each gait's fixed point on its own (per-gait windows, relaxation, Anderson
mixing and retries; :func:`workbench.hydro.simulator.simulate`), so a batch can be cut into
contiguous parts, each part swum in another process and the parts' results put back together in
order. :class:`SimWorkers` does that for a :class:`~workbench.gait.problem.GaitProblem`: every
worker holds the problem (leg model, robot, settings, and the flow kernel the parent probed, so
no worker probes its own) and swims the parts it is sent; the parent concatenates objectives,
residuals, convergence and, when asked, the whole trajectories. How close the answers are to a
one-process run is measured by tests/gait/test_workers.py and docs/gaits.md "Workers".

Workers are spawned processes that die with the command (:func:`workbench.procs.process_pool`:
parent-death signal, Ctrl-C ignored in the workers, ended on any exception in the parent).
"""

from __future__ import annotations

import pickle
import time
from contextlib import contextmanager
from dataclasses import replace
from typing import Iterator

import numpy as np

from workbench.hydro.simulator import GaitBatch, Trajectory

#: the worker's problems, by tabulation mode (built in the worker from the pickled parts)
_STATE: dict = {}

#: Trajectory fields whose first axis is the gait
_BATCH_FIELDS = ("x_m", "y_m", "yaw_rad", "vx_mps", "vy_mps", "yaw_rate_rps", "leg_wrench", "body_wrench",
                 "leg_flow_mps", "residual_mps", "converged")


def resolve_workers(value) -> int:
    """The number of worker processes a ``workers`` setting means now (``auto``: the idle cores)."""
    from workbench.threads import AUTO, idle_cores

    return idle_cores() if value == AUTO else max(1, int(value))


def _init(blob: bytes, torch_threads: int) -> None:
    """Worker initializer: unpickle the problem's parts; torch on ``torch_threads`` threads."""
    import sys

    parts = pickle.loads(blob)
    if "torch" in sys.modules:
        import torch

        torch.set_num_threads(torch_threads)
    _STATE["parts"] = parts


def _problem(mode: str):
    """The worker's problem with the given tabulation mode (made once per mode)."""
    if mode not in _STATE:
        from workbench.gait.problem import GaitProblem

        p = _STATE["parts"]
        problem = GaitProblem(p["spec"], p["leg_model"], p["robot"], space=p["space"], sim=p["sim"],
                              tabulation=replace(p["tabulation"], mode=mode))
        problem._flow_kernel = p["flow_kernel"]
        _STATE[mode] = problem
    return _STATE[mode]


def _swim(gaits: GaitBatch, initial_flow, mode: str, full: bool) -> dict:
    """One part: swim it, return objectives, residuals, convergence, the work counters (and the trajectories)."""
    from workbench.gait.objectives import objectives
    from workbench.gait.problem import EvaluationLog

    c0 = time.process_time()
    problem = _problem(mode)
    problem.log = EvaluationLog()
    traj = problem.simulate(gaits, initial_flow)
    return {"f": objectives(traj, problem.spec), "residual": traj.residual_mps, "converged": traj.converged,
            "iterations": traj.iterations, "traj": traj if full else None,
            "unconverged": problem.log.unconverged, "table": dict(problem.log.table),
            "cpu_s": time.process_time() - c0}


def concatenate(parts: list[Trajectory]) -> Trajectory:
    """One trajectory of the gaits of several, in order (same time axis and model)."""
    if len(parts) == 1:
        return parts[0]
    g = [t.gaits for t in parts]
    gaits = replace(g[0], **{k: np.concatenate([getattr(x, k) for x in g]) for k in
                             ("theta_h_min_deg", "theta_k_max_deg", "frequency_hz", "alpha_rad")})
    return replace(parts[0], gaits=gaits, iterations=max(t.iterations for t in parts),
                   **{k: np.concatenate([getattr(t, k) for t in parts]) for k in _BATCH_FIELDS})


class SimWorkers:
    """Swims gait batches in worker processes, each part of a batch in one worker, results in order."""

    def __init__(self, executor, workers: int):
        self.executor = executor
        self.workers = workers
        #: CPU seconds of the parts, all of them and the busiest part of each batch (their sum is the
        #: time a batch-by-batch run needs on idle cores, one per worker: load-independent balance measure)
        self.cpu_s = 0.0
        self.busiest_cpu_s = 0.0

    def parts(self, n: int) -> list[np.ndarray]:
        """The contiguous index ranges a batch of ``n`` gaits is cut into (one per worker, none empty)."""
        return [p for p in np.array_split(np.arange(n), min(self.workers, n)) if p.size]

    def swim(self, gaits: GaitBatch, initial_flow: np.ndarray | None, mode: str, full: bool) -> dict:
        """Swim a batch across the workers; the parts' results concatenated in the batch's order."""
        jobs = [self.executor.submit(_swim, gaits.rows(idx), None if initial_flow is None else initial_flow[idx],
                                     mode, full) for idx in self.parts(len(gaits))]
        res = [j.result() for j in jobs]
        self.cpu_s += sum(r["cpu_s"] for r in res)
        self.busiest_cpu_s += max(r["cpu_s"] for r in res)
        return {"f": np.concatenate([r["f"] for r in res]), "residual": np.concatenate([r["residual"] for r in res]),
                "converged": np.concatenate([r["converged"] for r in res]),
                "traj": concatenate([r["traj"] for r in res]) if full else None,
                "unconverged": sum(r["unconverged"] for r in res), "tables": [r["table"] for r in res]}


@contextmanager
def sim_workers(problem, workers: int) -> Iterator[SimWorkers | None]:
    """Worker processes for ``problem`` (None for one worker: everything stays in this process).

    The parent probes the leg model's flow kernel once (as a one-process run does) and hands it
    to the workers; each worker runs torch on its share of this process's torch threads.
    """
    if workers <= 1:
        yield None
        return
    import sys

    from workbench.procs import process_pool

    if problem.tabulation.mode != "never" and problem._flow_kernel is None:
        problem.model_for(problem.space.gaits(problem.space.xl[None, :]))  # probes the kernel (tabulated models)
    threads = 1
    if "torch" in sys.modules:
        import torch

        threads = max(1, torch.get_num_threads() // workers)
    blob = pickle.dumps({"spec": problem.spec, "leg_model": problem.leg_model, "robot": problem.robot,
                         "space": problem.space, "sim": problem.sim, "tabulation": problem.tabulation,
                         "flow_kernel": problem._flow_kernel})
    with process_pool(workers, initializer=_init, initargs=(blob, threads)) as ex:
        yield SimWorkers(ex, workers)
