"""NSGA-II on the gait problem: the problem contract, determinism, re-simulation, mirror images, vs random search."""

import json

import numpy as np
import pytest
from models import small_lstm

from workbench.gait.config import OptimizeSettings, TaskSettings
from workbench.gait.objectives import TaskSpec
from workbench.gait.optimize import optimize_task
from workbench.gait.problem import GaitProblem, SimSettings
from workbench.gait.run import NSGA2Settings, build_algorithm, run_nsga2, run_random
from workbench.gait.space import GaitSpace
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.simulator import GaitBatch

STRAIGHT = TaskSpec("straight", cap_s=6.0, finish_distance_m=0.2)
TURN = TaskSpec("turn", cap_s=8.0, target_yaw_deg=45.0)
REF = {"straight": (0.5, 1.0, 7.0), "turn": (3.0, 1.0, 9.0)}


def _config(task_spec, pop=12, gens=4, seed=0, **kw):
    return OptimizeSettings(tasks={task_spec.task: TaskSettings(task_spec, REF[task_spec.task])},
                          nsga2=NSGA2Settings(pop_size=pop, n_gen=gens, seed=seed), **kw)


def test_problem_evaluates_a_population_in_one_simulation(robot):
    problem = GaitProblem(STRAIGHT, EmpiricalFormula(), robot)
    x = problem.space.sample(10, np.random.default_rng(0))
    out = {}
    problem._evaluate(x, out)
    assert out["F"].shape == (10, 3) and np.all(np.isfinite(out["F"]))
    assert problem.log.calls == 1 and problem.log.gaits == 10
    # a gait's objectives do not depend on the rest of the population
    alone = problem.evaluate_gaits(problem.space.gaits(x[3:4]))[0]
    np.testing.assert_allclose(alone[0], out["F"][3], rtol=1e-12)
    assert problem.n_var == 7 and problem.n_obj == 3
    np.testing.assert_allclose(problem.xl, [-50, -80, 0.2, 0, 0, 0, 0])
    np.testing.assert_allclose(problem.xu, [10, -20, 0.65] + [2 * np.pi] * 4)


def test_same_seed_same_result_and_other_seed_differs(robot):
    a = optimize_task(_config(STRAIGHT, seed=3), "straight", EmpiricalFormula(), robot, model_label="ef", plots=False)
    b = optimize_task(_config(STRAIGHT, seed=3), "straight", EmpiricalFormula(), robot, model_label="ef", plots=False)
    c = optimize_task(_config(STRAIGHT, seed=4), "straight", EmpiricalFormula(), robot, model_label="ef", plots=False)
    assert json.dumps(a.gait_doc) == json.dumps(b.gait_doc)
    assert json.dumps(a.controller_doc) == json.dumps(b.controller_doc)
    assert not np.array_equal(a.retained.x, c.retained.x)


def test_retained_gaits_resimulated_from_the_file_reproduce_their_objectives(robot):
    o = optimize_task(_config(STRAIGHT), "straight", EmpiricalFormula(), robot, model_label="ef", plots=False)
    assert o.metrics["resim_max_rel_diff"] < 1e-9
    doc = json.loads(json.dumps(o.gait_doc))        # through JSON, as a reader gets it
    gaits = GaitBatch.from_params([s["params"] for s in doc["solutions"]])
    f = GaitProblem(STRAIGHT, EmpiricalFormula(), robot).evaluate_gaits(gaits)[0]
    recorded = np.array([[s["objectives"][k] for k in ("f1", "f2", "f3")] for s in doc["solutions"]])
    np.testing.assert_allclose(f, recorded, rtol=1e-9, atol=1e-12)


@pytest.mark.slow
def test_retained_lstm_gaits_carry_the_models_own_objectives(robot):
    """A tabulated search: the kept gaits were swum again directly, and that is what the file records."""
    from dataclasses import replace

    from workbench.gait.tabulate import TabulationSettings

    model = small_lstm(hidden=16)
    cfg = replace(_config(STRAIGHT, pop=8, gens=2), verify_direct=8, retain=4)
    o = optimize_task(cfg, "straight", model, robot, model_label="lstm", plots=False)
    assert o.metrics["tabulation"]["kind"] == "window" and o.metrics["verified_direct"] == 8
    assert max(o.metrics["verify_max_rel_diff"]) < 0.01
    doc = json.loads(json.dumps(o.gait_doc))
    gaits = GaitBatch.from_params([s["params"] for s in doc["solutions"]])
    # the model's own answer, solved far tighter than the check's 1e-5 m/s (which started from the tabulated
    # flow): the recorded objectives are it, to the fixed point's accuracy
    direct = GaitProblem(STRAIGHT, model, robot, tabulation=TabulationSettings(mode="never"),
                         sim=SimSettings(tol_mps=1e-9))
    recorded = np.array([[s["objectives"][k] for k in ("f1", "f2", "f3")] for s in doc["solutions"]])
    np.testing.assert_allclose(direct.evaluate_gaits(gaits)[0], recorded, rtol=2e-3, atol=1e-4)
    # without the direct check, the tabulated objectives come back as recorded
    o2 = optimize_task(replace(cfg, verify_direct=0), "straight", model, robot, model_label="lstm", plots=False)
    assert o2.metrics["resim_max_rel_diff"] < 1e-6


def test_mirrored_gait_turns_the_other_way(robot):
    o = optimize_task(_config(TURN, pop=12, gens=3), "turn", EmpiricalFormula(), robot, model_label="ef", plots=False)
    best = GaitSpace().gaits(o.retained.x[:1])
    left = TaskSpec("turn", cap_s=8.0, target_yaw_deg=45.0, turn_direction="left")
    right = TaskSpec("turn", cap_s=8.0, target_yaw_deg=45.0, turn_direction="right")
    p = GaitProblem(left, EmpiricalFormula(), robot)
    f, tr = p.evaluate_gaits(best)
    fm, trm = p.evaluate_gaits(best.mirrored())
    yaw, yaw_m = tr.yaw_rad[0, -1], trm.yaw_rad[0, -1]
    assert abs(yaw) > 0.2 and np.sign(yaw_m) == -np.sign(yaw)
    np.testing.assert_allclose(yaw_m, -yaw, rtol=1e-9)
    # counted in its own direction, the mirror image scores what the original scores
    own = left if yaw > 0 else right
    mirror_own = right if yaw > 0 else left
    np.testing.assert_allclose(GaitProblem(mirror_own, EmpiricalFormula(), robot).evaluate_gaits(best.mirrored())[0],
                               GaitProblem(own, EmpiricalFormula(), robot).evaluate_gaits(best)[0], rtol=1e-9)


@pytest.mark.slow
def test_nsga2_beats_random_search_at_equal_budget(robot):
    """Median over 5 seeds of the best S in NSGA-II's final population vs the best of as many random gaits."""
    settings = NSGA2Settings(pop_size=16, n_gen=8)
    nsga, rand = [], []
    for seed in range(5):
        problem = GaitProblem(STRAIGHT, EmpiricalFormula(), robot)
        res = run_nsga2(problem, NSGA2Settings(pop_size=16, n_gen=8, seed=seed), REF["straight"])
        nsga.append(res.s[0])
        rand.append(run_random(problem, settings.evaluations, seed=seed, batch=16).s[0])
        assert res.evaluations == settings.evaluations
    print(f"best S, median over 5 seeds: NSGA-II {np.median(nsga):.3f}, random search {np.median(rand):.3f}")
    assert np.median(nsga) < np.median(rand)


def test_ask_and_tell_loop_matches_minimize(robot):
    """A pool-in-the-loop campaign can drive the same algorithm step by step."""
    settings = NSGA2Settings(pop_size=8, n_gen=3, seed=5)
    p1 = GaitProblem(STRAIGHT, EmpiricalFormula(), robot)
    res = run_nsga2(p1, settings, REF["straight"])
    p2 = GaitProblem(STRAIGHT, EmpiricalFormula(), robot)
    algorithm = build_algorithm(settings)
    algorithm.setup(p2, termination=("n_gen", settings.n_gen), seed=settings.seed, verbose=False)
    while algorithm.has_next():
        pop = algorithm.ask()
        algorithm.evaluator.eval(p2, pop)       # or: swim them in the pool and set F by hand
        algorithm.tell(infills=pop)
    f = algorithm.pop.get("F")
    np.testing.assert_allclose(np.sort(f[:, 0]), np.sort(res.f[:, 0]))
