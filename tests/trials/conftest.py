"""Shared fixtures: small virtual pools rendered once per session (real mp4v files through OpenCV)."""

import pytest
from trials_helpers import SMALL, fast_straight, fast_turn

from workbench.virtual_lab.pool import PoolSettings, PoolTrial, circle_path, generate_pool, straight_path


@pytest.fixture(scope="session")
def small_pool(tmp_path_factory):
    """Two models, a straight run and a turn each: fast trials at 480x270."""
    out = tmp_path_factory.mktemp("pools") / "small-pool"
    trials = [fast_straight("ef-straight-1", "EF"), fast_turn("ef-turn-1", "EF"),
              fast_straight("lstm-straight-1", "FED-LSTM"), fast_turn("lstm-turn-1", "FED-LSTM")]
    generate_pool(out, trials, settings=PoolSettings(**SMALL, seed=3), progress=False)
    return out


@pytest.fixture(scope="session")
def realistic_pool(tmp_path_factory):
    """The acceptance pool at the demo's look (640x360, 15 fps, glare, noise, blur, occlusions).

    A drifting straight run, a turn, a straight run that never finishes (60 s), a turn with a
    brief occlusion by a passing arm, and a straight run occluded mid-way.
    """
    out = tmp_path_factory.mktemp("pools") / "realistic-pool"
    t1 = PoolTrial("ef-straight-1", "straight", "EF", 1, *straight_path(speed_mps=0.1, drift_deg=6.0))
    t2 = PoolTrial("ef-turn-1", "turn", "EF", 1, *circle_path(radius_m=0.07, period_s=22.0, direction=-1))
    t3 = PoolTrial("ef-straight-2", "straight", "EF", 2, *straight_path(speed_mps=0.025, drift_deg=-10.0))
    t4 = PoolTrial("lstm-turn-1", "turn", "FED-LSTM", 1, *circle_path(radius_m=0.12, period_s=20.0),
                   occlusions=((9.0, 0.8),))
    t5 = PoolTrial("lstm-straight-1", "straight", "FED-LSTM", 1, *straight_path(speed_mps=0.11, drift_deg=-3.0),
                   occlusions=((8.0, 0.7),))
    settings = PoolSettings(seed=11, occlusion_fraction=0.0, workers=2)
    generate_pool(out, [t1, t2, t3, t4, t5], settings=settings, progress=False)
    return out
