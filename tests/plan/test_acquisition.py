"""Greedy integrated variance over an ensemble whose disagreement is planted at high flow speed."""

from __future__ import annotations

import numpy as np
import pytest
from plan_fixtures import planted_ensemble

from workbench.hydro.motion import JointSinusoid, LegMotion
from workbench.plan.acquisition import IntegratedVariance, RigRanges, greedy_select, random_candidates
from workbench.plan.region import Region


def _region(flow: float, f: float = 0.6) -> Region:
    """Two legs swept by the paper's motion at a constant flow speed; the last cycle is the region."""
    dt = 1 / 65
    t = np.arange(int(3 / f / dt)) * dt
    rows = []
    for alpha in (0.0, np.pi):
        p = dict(theta_h_min_deg=-30.0, theta_h_max_deg=-100.0, theta_k_min_deg=80.0, theta_k_max_deg=-60.0,
                 frequency_hz=f, phi_rad=np.pi / 3, alpha_rad=alpha)
        rows.append(JointSinusoid.from_params(p).evaluate(t))
    arr = [np.stack([r[i] for r in rows]) for i in range(6)]
    motion = LegMotion(dt, arr[0], arr[1], arr[2], arr[3], np.full_like(arr[0], flow), arr[4], arr[5])
    ticks = np.stack([np.linspace(len(t) - 1 - 1 / f / dt, len(t) - 1, 8).round().astype(int)] * 2)
    return Region(motion, ticks, np.full(ticks.shape, 1 / ticks.size), ("a", "b"), ("planted",))


RANGES = RigRanges(flow_speeds_mps=(0.0, 0.1, 0.2, 0.3), setup_s=30.0)


def test_runs_go_where_the_members_disagree_in_the_region():
    ens = planted_ensemble()
    cands = random_candidates(RANGES, 48, seed=1)
    iv = IntegratedVariance(ens, _region(0.25), cands, lengthscale=0.8, points_per_run=4)
    sel = greedy_select(iv, 4, RANGES)
    flows = [cands[j].flow_speed_mps for j in sel.chosen]
    # members disagree only above 0.15 m/s: the region sits at 0.25; runs below 0.15 teach nothing there
    assert all(u >= 0.2 for u in flows), flows
    assert sel.total_after < 0.9 * sel.total_before
    # each run removes what the ones before it left: diminishing returns, and the removed variance adds up
    assert sel.gains == sorted(sel.gains, reverse=True)
    assert sum(sel.gains) == pytest.approx(sel.total_before - sel.total_after, rel=1e-6)


def test_a_region_where_members_agree_has_nothing_to_gain():
    ens = planted_ensemble()
    cands = random_candidates(RANGES, 32, seed=2)
    iv = IntegratedVariance(ens, _region(0.05), cands, lengthscale=0.8, points_per_run=4)
    sel = greedy_select(iv, 2, RANGES)
    assert sel.total_before == pytest.approx(0.0, abs=1e-12)
    assert max(sel.gains) == pytest.approx(0.0, abs=1e-12)


def test_a_run_far_from_the_region_in_state_space_counts_little():
    """Localisation: at the same flow, a stroke far from the region's informs it less than a near one."""
    ens = planted_ensemble()
    near = RANGES.params(-30.0, -60.0, 0.6, np.pi / 3)
    far = RANGES.params(10.0, -20.0, 0.2, 5 * np.pi / 3)
    from workbench.plan.acquisition import Candidate

    cands = [Candidate(near, 0.25, 5), Candidate(far, 0.25, 5)]
    iv = IntegratedVariance(ens, _region(0.25), cands, lengthscale=0.5, points_per_run=4)
    g = iv.gains(np.ones(2, bool))
    assert g[0] > 3 * g[1] > 0
