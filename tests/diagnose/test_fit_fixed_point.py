"""A fit whose columns read its own coefficients (a crosstalk's guard) is iterated to its fixed point.

Measured (EF, no reference, the probe's 3 % ty-from-fy crosstalk, 12-set rich campaign): once the
crosstalk was claimed, 39 of 136 fits swung back and forth instead of settling. With a fixed
circulatory lag added, the passes alternated between two states (held-out error 0.1738 and 0.1723,
training error 2555 and 2782, above the 2627 of the fit without the lag), and which state a
judgement met decided the lag's claim (t +5.7 in the final check, -6.0 in the report). Damped steps
make such a swing settle (there: training error 2748, held-out 0.1727, and the lag no longer helps).

Here the fit itself is replaced by a linear map with a known fixed point, so the iteration alone
is tested: a map that swings (eigenvalue -1) and one that settles by itself.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from workbench.diagnose import problem as problem_mod
from workbench.diagnose.problem import FitSettings, Problem, _reverses, fit_settled

FIXED = {"a.x": 0.7, "b.y": -0.3}


def _problem(monkeypatch, gain: float, se: float = 1e-3, settled: bool = False):
    """``Problem.fit`` on a stand-in whose every pass maps the coefficients c to c* + gain (c - c*), standard errors ``se``."""
    calls = []

    def grams(config, coefs, names, sets, surrogate):
        calls.append(dict(coefs))
        return dict(coefs)

    def fit(gr, w, hac, fixed):
        new = {k: v + gain * (gr.get(k, 0.0) - v) for k, v in FIXED.items()}
        return SimpleNamespace(coefs=lambda: dict(new), stderr=lambda: dict.fromkeys(new, se))

    monkeypatch.setattr(problem_mod, "_reads_prediction", lambda config: True)
    monkeypatch.setattr(problem_mod.lsq, "fit", fit)
    stub = SimpleNamespace(settings=FitSettings(passes=3, damped_passes=8, settle_rounds=4), weights=np.ones(6),
                           grams=grams)
    stub.fit = lambda config, coefs, names=None: Problem.fit(stub, config, coefs, names)
    config = SimpleNamespace(actives=[])
    if settled:
        return (lambda start: fit_settled(stub, config, start)), calls
    return (lambda start: Problem.fit(stub, config, start)), calls


def test_passes_that_swing_are_damped_to_the_fixed_point(monkeypatch):
    run, calls = _problem(monkeypatch, gain=-1.2)
    out = run({"a.x": 0.2, "b.y": 0.1}).coefs()
    assert out == pytest.approx(FIXED, rel=1e-3)
    assert len(calls) > 3


def test_undamped_a_swing_stays_unsettled(monkeypatch):
    """What the test above needs: never damped, the same map ends three passes away from its fixed point."""
    run, calls = _problem(monkeypatch, gain=-1.2)
    monkeypatch.setattr(problem_mod, "_reverses", lambda move, last: False)
    fit = run({"a.x": 0.2, "b.y": 0.1})
    out = fit.coefs()
    assert len(calls) == 3 and abs(out["a.x"] - FIXED["a.x"]) > 0.5
    # and the fit says so: its last pass moved a.x by about 1.6 (from -0.02 to 1.56), over a thousand standard errors
    fp = fit.fixed_point
    assert not fp.settled and fp.passes == 3 and fp.worst == "a.x" and fp.step_se > 1000
    assert "not reached after 3 passes" in fp.note() and "a.x" in fp.note()


def test_a_damped_swing_that_settles_says_so(monkeypatch):
    run, _ = _problem(monkeypatch, gain=-1.2)
    fp = run({"a.x": 0.2, "b.y": 0.1}).fixed_point
    assert fp.settled and fp.change < 1e-3


def test_a_last_move_within_the_noise_counts_as_settled(monkeypatch):
    """Three plain passes of a slowly contracting map end 0.3 ** 3 of the way: unsettled against tight
    standard errors, settled against wide ones (more passes would not change what the fit says)."""
    run, _ = _problem(monkeypatch, gain=0.3, se=1e-3)
    tight = run({"a.x": 0.2, "b.y": 0.1}).fixed_point
    run, _ = _problem(monkeypatch, gain=0.3, se=10.0)
    wide = run({"a.x": 0.2, "b.y": 0.1}).fixed_point
    assert tight.change > 1e-3 and wide.change > 1e-3
    assert not tight.settled and tight.step_se > 1
    assert wide.settled and wide.step_se < 0.1


def test_passes_that_settle_by_themselves_are_not_damped(monkeypatch):
    """A contracting map keeps its plain passes (the results of settling fits do not change)."""
    run, calls = _problem(monkeypatch, gain=0.3)
    out = run({"a.x": 0.2, "b.y": 0.1}).coefs()
    assert len(calls) == 3
    # three plain passes: the error shrinks by 0.3 each, and the steps are never halved
    assert out["a.x"] == pytest.approx(0.7 + 0.3 ** 3 * (0.2 - 0.7))


def test_reversal_is_a_step_back_against_the_last():
    assert _reverses({"a": 1.0, "b": -0.5}, {"a": -0.9, "b": 0.6})
    assert not _reverses({"a": 0.3, "b": 0.1}, {"a": 1.0, "b": 0.4})
    assert not _reverses({"a": 0.0}, {"a": 1.0})


def test_fits_claims_are_judged_on_are_continued_to_their_fixed_point(monkeypatch):
    """The slow map above, unsettled after one call's three passes, settles when continued (fit_settled);
    its record counts every pass, and a map that settles in one call is not fitted again."""
    run, calls = _problem(monkeypatch, gain=0.3, se=1e-3, settled=True)
    fit = run({"a.x": 0.2, "b.y": 0.1})
    assert fit.fixed_point.settled and fit.fixed_point.passes == len(calls) > 3
    assert fit.coefs() == pytest.approx(FIXED, rel=1e-3)
    run, calls = _problem(monkeypatch, gain=0.3, se=10.0, settled=True)
    assert run({"a.x": 0.2, "b.y": 0.1}).fixed_point.passes == len(calls) == 3
