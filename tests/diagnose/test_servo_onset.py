"""The servo's onset evidence (``ServoLag.seed``): the delay between the commanded and the measured start of motion.

Rich-truth campaigns (physics the EF lacks: its magnitudes are wrong, its timing is not), delays
planted by the tests' own formulas (``planting.py``: load-cell readings delayed against the trigger
line; a servo's command re-timed). The seed only starts a selection branch; whether the branch is
kept is the held-out test's business (``test_servo_noref.py``, slow).
"""

from __future__ import annotations

import battery  # noqa: E402  (tests/diagnose/battery.py: a broken import must fail, not skip)
import numpy as np
import planting  # noqa: E402
import pytest


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    return battery.Bench(tmp_path_factory.mktemp("onset"), n_sets=4)


def _problem(bench, folder, drop_rest: bool = False):
    return bench.problem(folder, drop_rest=drop_rest)


def _planted(bench, name, plant):
    return planting.copy_campaign(bench.new_campaign(), bench.root / name, [plant])


def test_the_clean_rich_campaign_gives_no_seed(bench):
    from workbench.diagnose.effects.servo import ServoLag, onset_delay

    problem = _problem(bench, bench.new_campaign())
    delay, ratio, runs = onset_delay(problem)
    assert runs >= 6
    # the EF's magnitudes are wrong on the rich truth, its timing is not
    assert abs(delay) <= 0.006, delay
    assert ServoLag().seed(problem) is None


@pytest.mark.parametrize("dead_s", [0.025, 0.045])
def test_a_dead_time_is_seen_at_the_onsets(bench, dead_s):
    from workbench.diagnose.effects.servo import ServoLag

    problem = _problem(bench, _planted(bench, f"dead{int(dead_s * 1000)}", planting.servo_dead_time(dead_s)))
    seeded = ServoLag().seed(problem)
    assert seeded is not None
    nl, why = seeded
    assert abs(nl["tau_s"] - dead_s) <= 0.004, nl
    assert f"{1000 * nl['tau_s']:.0f} ms" in why


def test_a_commanded_servo_with_a_lag_seeds_its_delay(bench):
    from workbench.diagnose.effects.servo import ServoLag

    # 10 ms dead time + 40 ms first-order lag (tau 50 ms): a lag moves the onset less than its time constant
    problem = _problem(bench, _planted(bench, "cmd-servo", planting.servo(dead_s=0.01, lag_s=0.04)))
    seeded = ServoLag(shapes="lag").seed(problem)
    assert seeded is not None
    nl, _ = seeded
    assert set(nl) == {"tau_s"}
    assert 0.02 <= nl["tau_s"] <= 0.06, nl


def test_no_rest_stretch_no_seed(bench):
    from workbench.diagnose.effects.servo import ServoLag, onset_delay

    problem = _problem(bench, _planted(bench, "dead-norest", planting.servo_dead_time(0.04)), drop_rest=True)
    assert onset_delay(problem) is None
    assert ServoLag().seed(problem) is None


def test_the_seed_options_are_the_effects_own(bench):
    from workbench.diagnose.effects.servo import ServoLag

    s = ServoLag.from_options({"onset_min_s": 0.05, "onset_window_s": 0.1})
    assert s.options()["onset_min_s"] == 0.05 and s.options()["onset_window_s"] == 0.1
    problem = _problem(bench, _planted(bench, "dead25b", planting.servo_dead_time(0.025)))
    assert s.seed(problem) is None  # 25 ms is below this lab's 50 ms threshold
    assert np.isclose(ServoLag().seed(problem)[0]["tau_s"], 0.025, atol=0.004)


class _LateModel:
    """A stand-in for a learned model whose own start of force comes 30 ms late (the EF's output delayed)."""

    name = "late"

    def __init__(self, late_s: float = 0.03):
        from workbench.hydro.legmodel import LegForceModel, load_leg_model

        self.ef = load_leg_model("ef")
        self.late_s = late_s
        LegForceModel.register(type(self))

    def wrench(self, motion):
        w = self.ef.wrench(motion)
        t = np.arange(w.shape[1]) * motion.dt_s
        out = np.empty_like(w)
        for b in range(w.shape[0]):
            for c in range(w.shape[2]):
                out[b, :, c] = np.interp(t - self.late_s, t, w[b, :, c])
        return out


def test_the_onsets_are_timed_against_the_ef_not_a_late_base_model(bench):
    from workbench.diagnose.chain import Lowpass
    from workbench.diagnose.data import prepare
    from workbench.diagnose.effects.servo import ServoLag
    from workbench.diagnose.problem import Problem
    from workbench.errors import ModelError

    folder = _planted(bench, "dead25-late", planting.servo_dead_time(0.025))
    problem = Problem(prepare(bench.frame(folder)), _LateModel(), Lowpass(6.0, 4))
    # against the base model's own (late) start of force the 25 ms look like -5 ms: no seed
    assert ServoLag(onset_model="base").seed(problem) is None
    nl, _ = ServoLag().seed(problem)
    assert abs(nl["tau_s"] - 0.025) <= 0.004, nl
    with pytest.raises(ModelError, match="onset_model"):
        ServoLag(onset_model="lstm")
    with pytest.raises(ModelError, match="onset_min_s must be a number"):
        ServoLag(onset_min_s="8 ms")


def test_a_mount_mode_already_claimed_explains_its_late_onset(bench):
    """A mount mode starts the force late too (4.5 Hz: 46 ms); once the paths claimed it, it seeds nothing."""
    from workbench.diagnose.chain import Active, Configuration
    from workbench.diagnose.effects.resonance import StructuralResonance
    from workbench.diagnose.effects.servo import ServoLag

    problem = _problem(bench, _planted(bench, "mode45", planting.mode(4.5, 0.08)))
    alone = ServoLag().seed(problem, Configuration())
    assert alone is not None and alone[0]["tau_s"] >= 0.02, alone
    claimed = Configuration([Active(StructuralResonance(), {"f_n_hz": 4.5, "zeta": 0.08})])
    assert ServoLag().seed(problem, claimed) is None
