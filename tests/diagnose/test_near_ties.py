"""Near ties of the greedy path (``SelectionSettings.tie_branches``): which runner-up is kept for a branch of its own.

The science is measured on the fourth probe (docs/diagnose.md, section 3 'Near ties'): a command servo beside a
static hip torque, where the greedy pick between two pairs of force effects within 1 % stalled the path. These
tests hold the bookkeeping: a runner-up is a near tie only within ``tie_ratio`` of the pick, sharing none of its
effects, acceptable, and only the first ``tie_branches`` are kept.
"""

from __future__ import annotations

from types import SimpleNamespace

from workbench.diagnose.chain import Configuration
from workbench.diagnose.selection import StepwiseSelection, _Path
from workbench.diagnose.selection_records import SelectionSettings


def _cand(llr: float, *names: str, ok: bool = True):
    return SimpleNamespace(ok=ok, test={"llr": llr}, effects=[SimpleNamespace(name=n) for n in names],
                           label="+".join(names))


def _path() -> _Path:
    return _Path(Configuration(), [], None, {}, [], [], {})


def test_a_runner_up_within_the_ratio_sharing_no_effect_is_kept_the_best_of_them():
    sel = StepwiseSelection(SelectionSettings(tie_branches=1, tie_ratio=0.98))
    best = _cand(6049.0, "normal_force_law", "added_mass_kc")
    near = _cand(5983.0, "link_drag", "rotating_added_mass")      # 98.9 % of the pick
    nearer_but_shared = _cand(6040.0, "normal_force_law", "link_inertia")
    far = _cand(5000.0, "lateral_force")
    refused = _cand(6048.0, "wagner_lag", ok=False)
    path = _path()
    sel._near_ties(path, [best, near, nearer_but_shared, far, refused], best, 0.01)
    assert [b.forced for b in path.ties] == [near]
    assert path.ties[0].level == 0.01
    assert path.ties[0].path is not path  # the path before the step, apart from the one that goes on


def test_no_tie_outside_the_ratio_and_no_more_than_the_budget():
    sel = StepwiseSelection(SelectionSettings(tie_branches=1, tie_ratio=0.98))
    best = _cand(100.0, "a")
    path = _path()
    sel._near_ties(path, [best, _cand(97.9, "b")], best, 0.01)
    assert path.ties == []
    sel._near_ties(path, [best, _cand(99.0, "c")], best, 0.01)
    sel._near_ties(path, [best, _cand(99.5, "d")], best, 0.01)  # a second tie: the budget (1) is spent
    assert [b.forced.label for b in path.ties] == ["c"]
    off = StepwiseSelection(SelectionSettings(tie_branches=0))
    p2 = _path()
    off._near_ties(p2, [best, _cand(99.9, "e")], best, 0.01)
    assert p2.ties == []
