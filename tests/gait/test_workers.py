"""Simulator workers: a batch cut into parts gives the whole batch's answers; 2 worker processes give 1's."""

import json
from dataclasses import replace

import numpy as np
import pytest
from models import small_lstm
from test_optimize import TURN, _config

from workbench.errors import ParamsError
from workbench.gait.config import config_from_dict, load_config
from workbench.gait.objectives import TaskSpec, objectives
from workbench.gait.optimize import optimize_task
from workbench.gait.problem import GaitProblem, SimSettings
from workbench.gait.space import GaitSpace
from workbench.gait.workers import concatenate
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.simulator import simulate

SIM = SimSettings().kwargs()
SPEC20 = TaskSpec("turn", cap_s=12.0, target_yaw_deg=90.0)


def _gaits(n, seed):
    return GaitSpace().gaits(GaitSpace().sample(n, np.random.default_rng(seed)))


def test_the_simulator_solves_each_gait_on_its_own(robot):
    """Parts of a batch swum separately give the whole batch's swims (EF, 12 s swims, random gaits).

    The parts stop iterating after other numbers of passes than the whole, so a gait's answer must
    not depend on when the others converge. It does not, bit for bit: the first part is one gait, and
    numpy's product of a single row (the body drag, every tick) takes another kernel whose last bits
    differ (2e-15 relative before the drag model sent one row through as two; docs/gaits.md "Workers").
    """
    gaits, cut = _gaits(7, seed=5), [0, 1, 4, 7]
    whole = simulate(gaits, EmpiricalFormula(), robot, duration_s=12.0, **SIM)
    parts = [simulate(gaits.rows(slice(a, b)), EmpiricalFormula(), robot, duration_s=12.0, **SIM)
             for a, b in zip(cut[:-1], cut[1:], strict=True)]
    joined = concatenate(parts)
    np.testing.assert_array_equal(joined.converged, whole.converged)
    for k in ("x_m", "y_m", "yaw_rad", "leg_flow_mps", "leg_wrench"):
        np.testing.assert_array_equal(getattr(joined, k), getattr(whole, k), err_msg=k)
    np.testing.assert_allclose(joined.residual_mps, whole.residual_mps, rtol=1e-3, atol=1e-9)
    np.testing.assert_array_equal(objectives(joined, SPEC20), objectives(whole, SPEC20))
    np.testing.assert_array_equal(joined.gaits.alpha_rad, gaits.alpha_rad)


@pytest.mark.slow
def test_a_tabulated_learned_model_is_batch_independent_too(robot):
    """The FED-LSTM-style net served from tables: parts give the whole batch's objectives bit for bit.

    Tables are per gait shape, and the start-up ticks are predicted afresh per gait (a gait whose
    legs moved), not for the whole call: before that, a gait's objectives moved by 2e-6 relative
    with the company it was swum in.
    """
    import torch

    torch.set_num_threads(1)
    spec = TaskSpec("turn", cap_s=10.0, target_yaw_deg=45.0)
    problem = GaitProblem(spec, small_lstm(), robot)
    gaits = _gaits(6, seed=2)
    f_whole = problem.evaluate_gaits(gaits)[0]
    f_parts = np.concatenate([problem.evaluate_gaits(gaits.rows(slice(a, b)))[0] for a, b in ((0, 2), (2, 6))])
    np.testing.assert_array_equal(f_parts, f_whole)


@pytest.mark.slow
def test_two_workers_give_one_workers_search_bit_for_bit(robot):
    """NSGA-II with 2 worker processes: the same populations, objectives and gait file as in one process."""
    cfg = _config(TURN, pop=12, gens=3)
    one = optimize_task(cfg, "turn", EmpiricalFormula(), robot, model_label="ef", plots=False, workers=1)
    two = optimize_task(cfg, "turn", EmpiricalFormula(), robot, model_label="ef", plots=False, workers=2)
    assert one.metrics["workers"] == 1 and two.metrics["workers"] == 2 and two.gait_doc["workers"] == 2
    np.testing.assert_array_equal(two.result.x, one.result.x)
    np.testing.assert_array_equal(two.result.f, one.result.f)
    np.testing.assert_array_equal(two.trajectories.x_m, one.trajectories.x_m)
    docs = [{k: v for k, v in o.gait_doc.items() if k != "workers"} for o in (one, two)]
    assert json.dumps(docs[0]) == json.dumps(docs[1])
    assert two.metrics["simulated_gaits"] == one.metrics["simulated_gaits"]
    assert two.metrics["unconverged_gaits"] == one.metrics["unconverged_gaits"]


@pytest.mark.slow
def test_two_workers_with_tables_and_the_direct_check(robot):
    """A tabulated learned model with its direct check in 2 workers: the kept gaits and their direct objectives agree."""
    import torch

    torch.set_num_threads(1)
    model = small_lstm()
    cfg = replace(_config(TURN, pop=10, gens=2), verify_direct=4, retain=3)
    one = optimize_task(cfg, "turn", model, robot, model_label="lstm", plots=False, workers=1)
    two = optimize_task(cfg, "turn", model, robot, model_label="lstm", plots=False, workers=2)
    assert one.metrics["verified_direct"] == two.metrics["verified_direct"] == 4
    np.testing.assert_array_equal(two.result.f, one.result.f)
    np.testing.assert_array_equal(two.retained.x, one.retained.x)
    np.testing.assert_array_equal(two.retained.f, one.retained.f)
    # the direct objectives are the model's own: a fresh direct swim in this process gives them back
    direct = GaitProblem(TURN, model, robot, tabulation=replace(cfg.tabulation, mode="never"))
    traj = direct.simulate(direct.space.gaits(two.retained.x))
    np.testing.assert_allclose(objectives(traj, TURN), two.retained.f, rtol=1e-4, atol=1e-6)


def test_workers_setting_is_checked_and_recorded():
    cfg = load_config()
    assert cfg.workers == "auto" and cfg.record()["workers"] == "auto"
    assert cfg.with_workers("3").workers == 3 and cfg.with_workers(None).workers == "auto"
    for bad in (0, -1, "two", 1.5, True):
        with pytest.raises(ParamsError, match=r"^pipelines/gait\.yaml, optimize\.workers: .*integer"):
            config_from_dict({"workers": bad}, "pipelines/gait.yaml")
