"""The mount mode's faster search criterion (``StructuralResonance.search_grams``) against the whole design.

A mode is planted into a rich-truth campaign with the tests' own formula (scipy's bilinear filter,
``planting.mode``); the search criterion built once from the reading's derivatives must rank the
mode's frequencies and dampings as the whole design passed through the mode and back does, and give
nearly its training error, beside force effects and alone. It screens candidates only; the reported
values come from the whole design (``selection_finish.refine``).
"""

from __future__ import annotations

import numpy as np
import pytest
from battery import Bench
from planting import copy_campaign, mode

from workbench.diagnose import lsq
from workbench.diagnose.chain import Active, Configuration, Lowpass
from workbench.diagnose.data import prepare
from workbench.diagnose.effects.resonance import StructuralResonance
from workbench.diagnose.library import default_library
from workbench.diagnose.problem import Problem
from workbench.hydro.ef import EmpiricalFormula

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def problem(tmp_path_factory):
    bench = Bench(tmp_path_factory.mktemp("mode-criterion"), n_sets=6)
    planted = copy_campaign(bench.new_campaign(), bench.root / "planted", [mode(4.5, 0.05)])
    return Problem(prepare(bench.frame(planted)), EmpiricalFormula(), Lowpass())


def _sse(problem, gr) -> float:
    return float(lsq.fit(gr, problem.weights, problem.settings.hac_lags).sse_block.sum())


@pytest.mark.parametrize("force", [(), ("added_mass_error", "drag_coefficient_error")])
def test_the_fast_criterion_ranks_modes_as_the_whole_design_does(problem, force):
    library = {e.name: e for e in default_library(list(force) or None)}
    config = Configuration()
    for name in force:
        config = config.with_effect(Active(library[name], {}))
    names = [f"{a.name}.{n}" for a in config.actives for n in a.effect.linear_names()]
    effect = StructuralResonance()
    fast = effect.search_grams(problem, config, {}, names)
    assert fast is not None
    points = [(f, z) for f in (3.0, 4.0, 4.5, 5.0, 6.0) for z in (0.05, 0.2)]
    exact, quick = [], []
    for f_n, zeta in points:
        nl = {"f_n_hz": f_n, "zeta": zeta}
        exact.append(_sse(problem, problem.grams(config.with_effect(Active(effect, nl)), {}, names, sets="search")))
        quick.append(_sse(problem, fast(nl)))
    exact, quick = np.array(exact), np.array(quick)
    # the same optimum on the grid (where the EF's own misfit puts it: 4 Hz with the EF alone, measured),
    # and the same training error within 1 % everywhere (measured: within 0.03 %)
    assert points[int(np.argmin(quick))] == points[int(np.argmin(exact))]
    assert np.max(np.abs(quick / exact - 1)) < 0.01
    # a criterion that ignored the mode would be flat: the planted mode moves it by far more than the gap
    assert np.ptp(exact) > 50 * np.max(np.abs(quick - exact))


def test_not_used_beside_a_sensor_effect_or_in_output_form(problem):
    library = {e.name: e for e in default_library(["sensor_drift"])}
    config = Configuration().with_effect(Active(library["sensor_drift"], {}))
    assert StructuralResonance().search_grams(problem, config, {}, []) is None
    assert StructuralResonance(form="output").search_grams(problem, Configuration(), {}, []) is None


@pytest.mark.parametrize("searched, values", [
    ("circulatory_lag", [{"tau_chords": t} for t in (0.1, 0.5, 1.5, 4.0, 12.0)]),
    ("servo_lag", [{"tau_s": t, "dead_share": 0.5} for t in (0.005, 0.02, 0.04, 0.08)]),
])
def test_searches_beside_a_claimed_mode_rank_values_as_the_whole_design_does(problem, searched, values):
    """Once a mode is claimed, another effect's search compares the reading through the inverse mode with the
    design without the mode (``Effect.search_reading``); it must rank that effect's values as the whole design
    through the mode and back does, with nearly its training error."""
    from workbench.diagnose.selection_search import _beside_filters

    library = {e.name: e for e in default_library(["added_mass_error", "drag_coefficient_error", searched])}
    config = Configuration([Active(library["added_mass_error"], {}), Active(library["drag_coefficient_error"], {}),
                            Active(StructuralResonance(), {"f_n_hz": 4.5, "zeta": 0.05})])
    names = ["added_mass_error.delta_kg", "drag_coefficient_error.delta_c"]
    effect = library[searched]
    quick = _beside_filters(problem, config, {}, names, effect)
    assert quick is not None
    exact = np.array([_sse(problem, problem.grams(config.with_effect(Active(effect, nl)), {}, names, sets="search"))
                      for nl in values])
    fast = np.array([_sse(problem, quick(nl)) for nl in values])
    assert int(np.argmin(fast)) == int(np.argmin(exact))
    assert np.max(np.abs(fast / exact - 1)) < 0.01
    assert np.ptp(exact) > 10 * np.max(np.abs(fast - exact))


def test_no_stand_in_beside_a_sensor_effect_or_an_output_form_mode(problem):
    from workbench.diagnose.selection_search import _beside_filters

    library = {e.name: e for e in default_library(["sensor_drift", "circulatory_lag"])}
    lag = library["circulatory_lag"]
    beside_sensor = Configuration([Active(StructuralResonance(), {"f_n_hz": 4.5, "zeta": 0.05}),
                                   Active(library["sensor_drift"], {})])
    assert _beside_filters(problem, beside_sensor, {}, [], lag) is None
    output_form = Configuration([Active(StructuralResonance(form="output"), {"f_n_hz": 4.5, "zeta": 0.05})])
    assert _beside_filters(problem, output_form, {}, [], lag) is None
    assert _beside_filters(problem, Configuration(), {}, [], lag) is None
