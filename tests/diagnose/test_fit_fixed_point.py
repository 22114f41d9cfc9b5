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
from workbench.diagnose.problem import FitSettings, Problem, _reverses

FIXED = {"a.x": 0.7, "b.y": -0.3}


def _problem(monkeypatch, gain: float):
    """``Problem.fit`` on a stand-in whose every pass maps the coefficients c to c* + gain (c - c*)."""
    calls = []

    def grams(config, coefs, names, sets, surrogate):
        calls.append(dict(coefs))
        return dict(coefs)

    def fit(gr, w, hac, fixed):
        new = {k: v + gain * (gr.get(k, 0.0) - v) for k, v in FIXED.items()}
        return SimpleNamespace(coefs=lambda: dict(new))

    monkeypatch.setattr(problem_mod, "_reads_prediction", lambda config: True)
    monkeypatch.setattr(problem_mod.lsq, "fit", fit)
    stub = SimpleNamespace(settings=FitSettings(passes=3, damped_passes=8), weights=np.ones(6),
                           grams=grams)
    config = SimpleNamespace(actives=[])
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
    out = run({"a.x": 0.2, "b.y": 0.1}).coefs()
    assert len(calls) == 3 and abs(out["a.x"] - FIXED["a.x"]) > 0.5


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
