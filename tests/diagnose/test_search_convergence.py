"""A nonlinear search that did not converge says so, and a claimed effect's final one reaches the diagnosis.

The local refinement (``selection_search._refine_locally``) finishes a grid's best value with a
bounded 1-D search or Nelder-Mead. Neither told whether it converged: Nelder-Mead's own success
flag is always false here (its ``fatol`` is absolute and never met on an SSE), and a 1-D search
whose best value sits at its window's edge has not found the optimum, which lies beyond. The
objectives here are the test's own quadratics, with known minima.
"""

from __future__ import annotations

from types import SimpleNamespace

from workbench.diagnose.chain import Active, Configuration
from workbench.diagnose.effects.base import SearchParam
from workbench.diagnose.loop import _unsettled
from workbench.diagnose.selection_records import SelectionSettings
from workbench.diagnose.selection_search import SIMPLEX_SPAN, _refine_locally

TAU = SearchParam("tau_s", (0.01, 0.02, 0.04), (0.001, 0.2), log=True)
ZETA = SearchParam("zeta", (0.05, 0.1), (0.01, 0.3))


def _bowl(**minimum):
    """Sum of squared distances from ``minimum`` (log distance for the log-scaled lag)."""
    import numpy as np

    def f(values):
        tau, *rest = values
        out = (np.log(tau) - np.log(minimum["tau_s"])) ** 2
        if rest:
            out += (rest[0] - minimum["zeta"]) ** 2 * 100
        return float(out)

    return f


def test_a_1d_search_near_its_optimum_converges():
    out, note = _refine_locally(SelectionSettings(), _bowl(tau_s=0.022), [TAU], [0.02], None, warm=True)
    assert note is None and abs(out[0] - 0.022) < 0.001


def test_a_1d_search_whose_optimum_lies_beyond_its_window_says_so():
    """Warm-started at 20 ms with a window of exp(+-0.7): the 100 ms optimum is outside; the search stops at the edge."""
    out, note = _refine_locally(SelectionSettings(), _bowl(tau_s=0.1), [TAU], [0.02], None, warm=True)
    assert note is not None and "edge of its search window" in note and "tau_s" in note
    assert out[0] < 0.045


def test_a_1d_search_out_of_evaluations_says_so():
    s = SelectionSettings(refine_evals=2)
    _, note = _refine_locally(s, _bowl(tau_s=0.025), [TAU], [0.02], None, warm=True)
    assert note is not None and "ran out of its 2 evaluations" in note


def test_nelder_mead_is_judged_by_its_simplex_not_its_success_flag():
    """Converged in x (its simplex under SIMPLEX_SPAN) it says nothing; cut off by its budget it says so."""
    bowl = _bowl(tau_s=0.03, zeta=0.12)
    out, note = _refine_locally(SelectionSettings(), bowl, [TAU, ZETA], [0.02, 0.1], None, warm=False)
    assert note is None and abs(out[0] - 0.03) < 0.001 and abs(out[1] - 0.12) < 0.002
    out, note = _refine_locally(SelectionSettings(refine_evals=2), bowl, [TAU, ZETA], [0.02, 0.1], None, warm=False)
    assert note is not None and "simplex still spans" in note and "tau_s, zeta" in note
    assert float(note.split("spans ")[1].split(" ")[0]) > SIMPLEX_SPAN


def test_a_claimed_effects_unconverged_final_search_reaches_the_diagnosis():
    """Only the claimed effects' notes are reported (an effect dropped afterwards is not the result)."""
    from workbench.diagnose.library import make_effect

    lag, lift = make_effect("servo_lag"), make_effect("lift")
    config = Configuration([Active(lag, {"tau_s": 0.02}), Active(lift, {})])
    final = SimpleNamespace(fixed_point=None)
    notes = {"servo_lag": "tau_s: its best value lies at the edge of its search window (the optimum is beyond it)",
             "structural_resonance": "f_n_hz, zeta: Nelder-Mead's simplex still spans 0.2 (log) units"}
    out = _unsettled(final, [], config, notes)
    assert out == [f"the final search of servo_lag did not converge ({notes['servo_lag']})"]
    assert _unsettled(final, [], config, {}) == []


def _coordinate_round(ridge: float):
    """A stand-in for one refinement round: exact coordinate minimisation of the test's own quadratic.

    With u = log tau - log 0.04 and w = log zeta - log 0.08, f = (u - ridge w)^2 + w^2 / 4 has its
    minimum at 40 ms, 0.08. With ``ridge`` 1 its valley runs diagonally and each round of
    one-at-a-time searches closes only a fifth of the way (as a dead time beside a mount mode
    crawls); with ``ridge`` 0 one round lands.
    """
    import numpy as np

    calls = []

    def round_(s, problem, config, coefs, names, notes):
        calls.append(1)
        nl = {a.name: dict(a.nl) for a in config.actives}
        w = np.log(nl["structural_resonance"]["zeta"] / 0.08)
        u = ridge * w                                   # tau given zeta
        w = ridge * u / (ridge ** 2 + 0.25)             # zeta given tau
        nl["servo_lag"]["tau_s"], nl["structural_resonance"]["zeta"] = 0.04 * float(np.exp(u)), 0.08 * float(np.exp(w))
        out = Configuration([Active(a.effect, nl[a.name]) for a in config.actives])
        return out, SimpleNamespace(coefs=lambda: {})

    return round_, calls


def test_refinement_rounds_run_until_trading_values_settle_and_flag_them_otherwise(monkeypatch):
    """Two searched effects on a diagonal valley: still moving after the last round, both are flagged."""
    import workbench.diagnose.selection_finish as F
    from workbench.diagnose.library import make_effect

    lag, mode = make_effect("servo_lag"), make_effect("structural_resonance")
    start = Configuration([Active(lag, {"tau_s": 0.03, "dead_share": 1.0}),
                           Active(mode, {"f_n_hz": 4.5, "zeta": 0.16})])
    problem = SimpleNamespace(search_notes={})
    round_, calls = _coordinate_round(ridge=1.0)
    monkeypatch.setattr(F, "_refine_round", round_)
    config, _ = F.refine(SelectionSettings(refine_rounds=3), problem, start, {}, [], None)
    assert len(calls) == 3
    assert set(problem.search_notes) == {"servo_lag", "structural_resonance"}
    assert "last of 3 refinement rounds" in problem.search_notes["structural_resonance"]
    assert "trade off with servo_lag" in problem.search_notes["structural_resonance"]
    # a valley across the axes: the second round moves nothing, the loop stops, nothing is flagged
    problem = SimpleNamespace(search_notes={})
    round_, calls = _coordinate_round(ridge=0.0)
    monkeypatch.setattr(F, "_refine_round", round_)
    config, _ = F.refine(SelectionSettings(refine_rounds=3), problem, start, {}, [], None)
    assert len(calls) == 2 and problem.search_notes == {}
    assert abs(config.nl_values()["structural_resonance.zeta"] - 0.08) < 1e-9


def test_one_searched_effect_is_refined_in_one_round(monkeypatch):
    import workbench.diagnose.selection_finish as F
    from workbench.diagnose.library import make_effect

    calls = []

    def round_(s, problem, config, coefs, names, notes):
        calls.append(1)
        return config, SimpleNamespace(coefs=lambda: {})

    monkeypatch.setattr(F, "_refine_round", round_)
    config = Configuration([Active(make_effect("servo_lag"), {"tau_s": 0.03, "dead_share": 1.0}),
                            Active(make_effect("lift"), {})])
    F.refine(SelectionSettings(refine_rounds=4), SimpleNamespace(search_notes={}), config, {}, [], None)
    assert len(calls) == 1
