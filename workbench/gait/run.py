"""Running the optimisation: NSGA-II (pymoo) or random search at the same budget, then ranking by S.

:func:`run_nsga2` is ``pymoo.optimize.minimize`` with a :class:`GenerationLog` callback that
records, per generation, the evaluations so far, the hypervolume of the population's
non-dominated set against a fixed reference point, and the best score S. The final population
is ranked by S and the best ``retain`` kept (the paper keeps 8 for hardware trials).
:func:`run_random` draws the same number of gaits uniformly: the baseline NSGA-II has to beat.
For an ask/tell loop (e.g. pool trials in the loop) use :func:`build_algorithm` with
``algorithm.setup(problem, seed=...)``, ``ask()`` and ``tell()`` as pymoo documents.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from workbench.gait.objectives import score
from workbench.gait.problem import GaitProblem


@dataclass(frozen=True)
class NSGA2Settings:
    """Algorithm settings (``nsga2`` in pipelines/gait.yaml); pymoo's defaults for the operators."""

    pop_size: int = 64
    n_gen: int = 50
    seed: int = 0
    crossover_prob: float = 0.9
    crossover_eta: float = 15.0
    mutation_eta: float = 20.0

    def __post_init__(self):
        if self.pop_size < 4 or self.n_gen < 1:
            from workbench.errors import SettingError

            raise SettingError("nsga2 needs pop_size >= 4 and n_gen >= 1", where="optimize.nsga2")

    @classmethod
    def from_dict(cls, doc: Mapping[str, Any] | None, path: str | None = None) -> "NSGA2Settings":
        """From the ``nsga2`` section of the parameter file ``path`` (workbench.params: unknown keys refused)."""
        from workbench.params import build

        return build(cls, doc, key="optimize.nsga2", path=path)

    @property
    def evaluations(self) -> int:
        """Gaits evaluated by a full run: the initial population plus pop_size offspring per generation."""
        return self.pop_size * self.n_gen


@dataclass(frozen=True)
class Generation:
    """One generation's record."""

    gen: int
    evaluations: int
    hypervolume: float
    best_score: float
    front_size: int
    seconds: float
    #: gaits of the population whose simulation did not converge (excluded from front, HV and best S)
    unconverged: int = 0


@dataclass
class OptimizeResult:
    """The final population ranked by S, the per-generation history and the work done."""

    x: np.ndarray            # (n, 7) decision vectors, best score first
    f: np.ndarray            # (n, 3)
    s: np.ndarray            # (n,)
    history: list[Generation] = field(default_factory=list)
    evaluations: int = 0
    seconds: float = 0.0
    method: str = "nsga2"
    #: (n,) whether each solution's simulation converged (converged ones rank first); None: all did
    converged: np.ndarray | None = None

    def __post_init__(self):
        if self.converged is None:
            self.converged = np.ones(len(self.s), bool)

    def best(self, k: int) -> "OptimizeResult":
        """The best ``k`` solutions."""
        return OptimizeResult(self.x[:k], self.f[:k], self.s[:k], self.history, self.evaluations, self.seconds,
                              self.method, self.converged[:k])


def rank(x: np.ndarray, f: np.ndarray, weights, converged: np.ndarray | None = None):
    """Sort solutions by S, every converged one before any unconverged one (ties keep their order).

    Returns x, f, s and the converged mask, sorted.
    """
    s = score(f, weights)
    converged = np.ones(len(s), bool) if converged is None else np.asarray(converged, bool)
    order = np.lexsort((s, ~converged))
    return x[order], f[order], s[order], converged[order]


def non_dominated(f: np.ndarray) -> np.ndarray:
    """Indices of the non-dominated rows of an (n, m) objective matrix (minimisation)."""
    from pymoo.util.nds.non_dominated_sorting import NonDominatedSorting

    if len(f) == 0:
        return np.zeros(0, int)
    return np.asarray(NonDominatedSorting().do(f, only_non_dominated_front=True), int)


def hypervolume(f: np.ndarray, reference: np.ndarray) -> float:
    """Hypervolume of the points dominating ``reference`` (a fixed point, so generations compare)."""
    from pymoo.indicators.hv import HV

    f = np.asarray(f, float)
    inside = f[np.all(f < reference, axis=1)]
    if len(inside) == 0:
        return 0.0
    return float(HV(ref_point=np.asarray(reference, float))(inside))


def build_algorithm(settings: NSGA2Settings):
    """NSGA-II (pymoo) with SBX crossover and polynomial mutation as the settings say."""
    from pymoo.algorithms.moo.nsga2 import NSGA2
    from pymoo.operators.crossover.sbx import SBX
    from pymoo.operators.mutation.pm import PM

    return NSGA2(pop_size=settings.pop_size, crossover=SBX(prob=settings.crossover_prob, eta=settings.crossover_eta),
                 mutation=PM(eta=settings.mutation_eta), eliminate_duplicates=True)


def _generation_log(reference: np.ndarray, weights, on_generation: Callable[[Generation], None] | None):
    """A pymoo Callback recording one :class:`Generation` per iteration (built lazily: pymoo import)."""
    from pymoo.core.callback import Callback

    class GenerationLog(Callback):
        """Per-generation hypervolume, best score and evaluations; calls ``on_generation``."""

        def __init__(self):
            super().__init__()
            self.records: list[Generation] = []
            self.t0 = time.perf_counter()

        def notify(self, algorithm):
            f = algorithm.pop.get("F")
            ok = _feasible(algorithm.pop)
            f = f[ok]
            front = f[non_dominated(f)]
            best = float(score(f, weights).min()) if len(f) else float("nan")
            rec = Generation(gen=int(algorithm.n_gen), evaluations=int(algorithm.evaluator.n_eval),
                             hypervolume=hypervolume(front, reference), best_score=best,
                             front_size=len(front), seconds=time.perf_counter() - self.t0,
                             unconverged=int((~ok).sum()))
            self.records.append(rec)
            if on_generation is not None:
                on_generation(rec)

    return GenerationLog()


def run_nsga2(problem: GaitProblem, settings: NSGA2Settings, reference, *,
              on_generation: Callable[[Generation], None] | None = None) -> OptimizeResult:
    """NSGA-II for ``n_gen`` generations; the final population ranked by the task's S."""
    from pymoo.optimize import minimize

    t0 = time.perf_counter()
    log = _generation_log(np.asarray(reference, float), problem.spec.weights, on_generation)
    res = minimize(problem, build_algorithm(settings), ("n_gen", settings.n_gen), seed=settings.seed,
                   callback=log, verbose=False, copy_algorithm=False)
    pop = res.algorithm.pop
    x, f, s, ok = rank(pop.get("X"), pop.get("F"), problem.spec.weights, _feasible(pop))
    return OptimizeResult(x, f, s, log.records, int(res.algorithm.evaluator.n_eval), time.perf_counter() - t0,
                          converged=ok)


def _feasible(pop) -> np.ndarray:
    """(n,) whether each individual's simulation converged (its constraint g <= 0; no constraint: all)."""
    g = pop.get("G")
    if g is None or np.size(g) == 0:
        return np.ones(len(pop), bool)
    return np.all(np.asarray(g, float).reshape(len(pop), -1) <= 0, axis=1)


def run_random(problem: GaitProblem, evaluations: int, seed: int, batch: int = 64) -> OptimizeResult:
    """Random search: ``evaluations`` gaits drawn uniformly in the bounds, ranked by S."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    xs, fs, oks = [], [], []
    for start in range(0, evaluations, batch):
        x = problem.space.sample(min(batch, evaluations - start), rng)
        xs.append(x)
        f, traj = problem.evaluate_gaits(problem.space.gaits(x))
        fs.append(f)
        oks.append(traj.converged)
    x, f, s, ok = rank(np.concatenate(xs), np.concatenate(fs), problem.spec.weights, np.concatenate(oks))
    return OptimizeResult(x, f, s, [], evaluations, time.perf_counter() - t0, method="random", converged=ok)
