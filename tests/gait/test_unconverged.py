"""Gaits whose simulation does not converge are penalised, ranked last, counted and marked, never silently kept."""

import json

import numpy as np

from workbench.gait.config import OptimizeSettings, TaskSettings
from workbench.gait.objectives import TaskSpec
from workbench.gait.optimize import optimize_task
from workbench.gait.problem import GaitProblem, SimSettings
from workbench.gait.run import NSGA2Settings, run_random
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.legmodel import LegForceModel

SPEC = TaskSpec("straight", cap_s=5.0, finish_distance_m=0.2)


class _StiffAtHighFrequency(LegForceModel):
    """The EF plus, on legs beating faster than 0.45 Hz, a huge added mass on the flow's acceleration.

    The force -m du/dt (centred difference: a one-tick look-ahead) with m = 30 kg per leg, far above
    the body's 2-3 kg, makes the legs' flow at one tick depend on itself with a loop gain above one:
    no fixed-point iteration converges there. Below 0.45 Hz it is the EF.
    """

    name = "stiff-fast-legs"
    _ef = EmpiricalFormula()

    def wrench(self, motion):
        out = self._ef.wrench(motion)
        u = np.asarray(motion.flow_speed_mps, float)
        du = np.gradient(u, motion.dt_s, axis=1) if u.shape[1] > 2 else np.zeros_like(u)
        fast = self.beat_hz(motion) > 0.45
        out[fast, :, 1] += -30.0 * du[fast]
        return out

    @staticmethod
    def beat_hz(motion):
        """Each leg's beat frequency: for a sinusoid, peak acceleration / peak rate = 2 pi f."""
        acc = motion.alpha_h_dps2 if motion.alpha_h_dps2 is not None else np.gradient(motion.omega_h_dps, axis=1)
        return np.abs(acc).max(axis=1) / (2 * np.pi * np.abs(motion.omega_h_dps).max(axis=1))

    def describe(self):
        return {"name": self.name}


def test_unconverged_gaits_are_penalised_counted_and_never_retained(robot):
    cfg = OptimizeSettings(tasks={"straight": TaskSettings(SPEC, (0.5, 1.0, 6.0))},
                         nsga2=NSGA2Settings(pop_size=12, n_gen=3, seed=1), retain=4,
                         simulation=SimSettings())
    model = _StiffAtHighFrequency()
    out = optimize_task(cfg, "straight", model, robot, model_label="stiff", plots=False)
    res = out.result
    # the stiff gaits were evaluated, did not converge and were selected away: the final population beats slowly
    assert out.metrics["unconverged_gaits"] > 0 and out.metrics["retained_unconverged"] == 0
    assert res.converged.all() and np.all(res.x[:, 2] <= 0.45)
    assert all(g.unconverged == 0 for g in res.history[-1:])
    # random search keeps them all: exactly the fast ones are unconverged, and they rank after every converged one
    rnd = run_random(GaitProblem(SPEC, model, robot), 16, seed=0)
    fast = rnd.x[:, 2] > 0.45
    assert fast.any() and (~fast).any()
    assert np.array_equal(rnd.converged, ~fast)
    assert not np.any(np.diff(rnd.converged.astype(int)) > 0)
    doc = json.loads(json.dumps(out.gait_doc))
    assert doc["unconverged_gaits"] == out.metrics["unconverged_gaits"]
    assert doc["simulated_gaits"] >= cfg.nsga2.evaluations
    assert all(s["converged"] for s in doc["solutions"])
    assert all(s["params"]["frequency_hz"] <= 0.45 for s in doc["solutions"])
    # the penalty is pymoo's constraint: violated exactly for the unconverged gaits
    problem = GaitProblem(SPEC, model, robot)
    x = np.array([[-20, -50, 0.3, 0, 0, np.pi, np.pi], [-20, -50, 0.6, 0, 0, np.pi, np.pi]])
    o = {}
    problem._evaluate(x, o)
    assert o["G"][0, 0] <= 0 < o["G"][1, 0]
    assert problem.log.unconverged == 1


def test_an_unconverged_gait_never_reaches_the_gait_file_or_a_figure(robot):
    """Fewer converged gaits than ``retain``: the gait file holds fewer gaits, none unconverged; none converged: error.

    Issue 14, done when: no gait file or report figure comes from an unconverged trajectory. Before,
    the best unconverged gaits filled the file up to ``retain``, marked ``converged: false``, and the
    trajectories figure drew their swims.
    """
    import pytest

    from workbench.errors import ConvergenceError
    from workbench.gait.space import GaitSpace

    def cfg(f_lo):
        return OptimizeSettings(tasks={"straight": TaskSettings(SPEC, (0.5, 1.0, 6.0))}, retain=8,
                              space=GaitSpace(frequency_hz=(f_lo, 0.65)),
                              nsga2=NSGA2Settings(pop_size=8, n_gen=1, seed=2), simulation=SimSettings())

    model = _StiffAtHighFrequency()
    out = optimize_task(cfg(0.3), "straight", model, robot, model_label="stiff", plots=True)
    slow = out.result.x[:, 2] <= 0.45
    assert 0 < slow.sum() < 8                                 # some of the population beat fast, some slow
    doc = json.loads(json.dumps(out.gait_doc))
    assert all(s["converged"] and s["params"]["frequency_hz"] <= 0.45 for s in doc["solutions"])
    assert len(doc["solutions"]) == slow.sum() == out.metrics["evaluations"] - out.metrics["dropped_unconverged"]
    assert out.metrics["retained_unconverged"] == 0 and out.trajectories.converged.all()
    assert len(out.trajectories) == len(doc["solutions"]) == len(out.controller_doc["gaits"])
    with pytest.raises(ConvergenceError, match="none of the 8 best straight gaits") as err:
        optimize_task(cfg(0.5), "straight", model, robot, model_label="stiff", plots=False)
    assert "\n" not in str(err.value)
