"""The selection's last steps: the joint refinement keeps a line's effect on its line; dropped claims are recorded.

Measured (FED-LSTM, the demo campaign re-measured with seed 11, a 2 Hz / 5 % flow tone planted):
the tone was claimed at step 1 (p 1e-20), then the final refinement, warm-started with a +-20 %
window, moved it to 1.797 Hz, a harmonic of every gait (0.3, 0.45, 0.6 Hz). There its per-run fit
took in the stroke-locked misfit, its off-peak fits gained exactly as much, and the backward check
dropped it without a trace in the selection record.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from workbench.diagnose import selection_finish
from workbench.diagnose.chain import Active, Configuration
from workbench.diagnose.library import make_effect
from workbench.diagnose.selection_records import SelectionSettings


def test_the_refinement_searches_a_tone_within_the_window_of_its_line(monkeypatch):
    seen = {}

    def search(s, problem, config, coefs, names, effect, grids=None, start=None, fast=True):
        seen.update(effect=effect.name, grids=grids, start=start, fast=fast)
        return {"tone_hz": 1.9989}, {}

    monkeypatch.setattr(selection_finish, "search", search)
    tone = make_effect("flow_unsteadiness")
    config = Configuration().with_effect(Active(tone, {"tone_hz": 2.0018}))
    problem = SimpleNamespace(surrogate_search=False, search_notes={}, fit=lambda cfg, coefs, names: ("fit", cfg))
    s = SelectionSettings()
    out, _ = selection_finish.refine(s, problem, config, {}, [], None)

    grid = np.asarray(seen["grids"]["tone_hz"])
    assert seen["effect"] == "flow_unsteadiness" and seen["start"] is None and seen["fast"] is False
    assert np.all(np.abs(grid - 2.0018) <= s.tone_window_hz + 1e-9), grid
    assert 2.0018 in grid and len(grid) >= 9
    # 1.8 Hz, the gaits' common harmonic the warm start reached, is outside the window
    assert grid.min() > 1.8
    assert [a.nl["tone_hz"] for a in out.actives] == [1.9989]


class _Fit(tuple):
    """A fit as the backward check reads it: ``("fit", configuration)``, one linear solve (nothing to settle)."""

    grams = None
    fixed_point = None

    def coefs(self):
        return {}


def _problem():
    """A problem whose fits are the configurations fitted (the judgements are the test's ``judge``)."""
    return SimpleNamespace(settings=SimpleNamespace(hac_lags=2, settle_rounds=4),
                           fit=lambda cfg, coefs, names: _Fit(("fit", cfg)))


def test_an_effect_the_backward_check_drops_leaves_a_row_in_the_record(monkeypatch):
    """A claim that does not survive the final check is not silently removed from the record."""
    weak = make_effect("lift")
    strong = make_effect("link_drag")
    config = Configuration().with_effect(Active(weak, {})).with_effect(Active(strong, {}))

    def judge(before, after, grams, hac, corr=None, null_sse=None, telling=None):
        gone = [a.name for a in after[1].actives if a.name not in {x.name for x in before[1].actives}]
        if gone == ["lift"]:
            return {"t": 0.3, "p": 0.38, "llr": 1.0, "n_blocks": 40}, np.full(6, 0.001)
        return {"t": 9.0, "p": 1e-12, "llr": 500.0, "n_blocks": 40}, np.full(6, 0.3)

    monkeypatch.setattr(selection_finish, "judge", judge)

    problem = _problem()
    steps = [SimpleNamespace(candidate=SimpleNamespace(effect=weak)),
             SimpleNamespace(candidate=SimpleNamespace(effect=strong))]
    table = []
    cfg, names, current, kept = selection_finish.backward_check(
        SelectionSettings(), problem, config, ["lift.c_l", "link_drag.cd_d_m"], _Fit(("fit", config)),
        steps, table)
    assert cfg.names() == ["link_drag"] and names == ["link_drag.cd_d_m"]
    assert [st.candidate.effect.name for st in kept] == ["link_drag"]
    assert len(table) == 1 and table[0]["effect"] == "lift" and not table[0]["ok"]
    assert "dropped in the final check" in table[0]["note"] and "p=0.38" in table[0]["note"]


def test_the_last_claim_left_is_judged_alone_after_its_partner_is_dropped(monkeypatch):
    """A pair's member that stays alone must earn its place alone (FED-LSTM, 25 ms dead time, 1 Dec 2026:
    `normal_force_law` + `loadcell_crosstalk` claimed as a pair, the crosstalk dropped by this check at p 0.011,
    and `normal_force_law` kept alone at p 0.038 because the check stopped at one effect)."""
    law = make_effect("normal_force_law")
    xt = make_effect("link_drag")  # any second effect: the judgements below are the test's
    config = Configuration().with_effect(Active(law, {})).with_effect(Active(xt, {}))
    judged = []

    def judge(before, after, grams, hac, corr=None, null_sse=None, telling=None):
        have = [a.name for a in after[1].actives]
        gone = [n for n in have if n not in {x.name for x in before[1].actives}]
        judged.append((gone, have))
        if gone == ["link_drag"]:
            return {"t": 2.3, "p": 0.011, "llr": 121.0, "n_blocks": 40}, np.full(6, 0.05)
        if gone == ["normal_force_law"] and have == ["normal_force_law"]:  # alone, against the base model
            return {"t": 1.8, "p": 0.038, "llr": 459.0, "n_blocks": 40}, np.full(6, 0.126)
        return {"t": 4.2, "p": 6e-5, "llr": 768.0, "n_blocks": 40}, np.full(6, 0.139)

    monkeypatch.setattr(selection_finish, "judge", judge)

    problem = _problem()
    steps = [SimpleNamespace(candidate=SimpleNamespace(effect=law)), SimpleNamespace(candidate=SimpleNamespace(effect=xt))]
    table = []
    cfg, names, _, kept = selection_finish.backward_check(
        SelectionSettings(), problem, config, ["normal_force_law.c_n90", "link_drag.cd_d_m"], _Fit(("fit", config)),
        steps, table)
    assert cfg.names() == [] and names == [] and kept == []
    assert [r["effect"] for r in table] == ["link_drag", "normal_force_law"]
    assert "alone, against the base model" in table[1]["note"] and "p=0.038" in table[1]["note"]
    assert "beside the others' final values" in table[0]["note"]
    assert (["normal_force_law"], ["normal_force_law"]) in judged


def test_an_entry_pruned_away_leaves_the_current_values():
    from workbench.diagnose.selection_finish import _live

    coefs = {"loadcell_crosstalk.x_fz_fy": 0.05, "loadcell_crosstalk.x_ty_fy": 0.0008, "sensor_drift.rate_fz": 1e-3,
             "link_drag.cd_d_m": 0.006}
    live = _live(coefs, ["loadcell_crosstalk.x_fz_fy", "sensor_drift.rate_fz", "link_drag.cd_d_m"],
                 ("loadcell_crosstalk.", "sensor_drift."))
    # the dropped ty entry no longer reaches the crosstalk's guard; other effects' values stay whatever their names
    assert live == {"loadcell_crosstalk.x_fz_fy": 0.05, "sensor_drift.rate_fz": 1e-3, "link_drag.cd_d_m": 0.006}
    assert _live(coefs, [], ("loadcell_crosstalk.",)) == {"sensor_drift.rate_fz": 1e-3, "link_drag.cd_d_m": 0.006}
