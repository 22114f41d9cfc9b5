"""The contract's scores on analytic trajectories (no video): exact values known in closed form."""

import numpy as np
import pytest

from workbench.errors import ConvergenceError, DataError
from workbench.trials.scoring import (
    CAP_S,
    MAX_RADIUS_PER_EXTENT,
    UndecidedError,
    first_crossing,
    fit_circle,
    score_straight,
    score_trajectory,
    score_turn,
)


def test_first_crossing_interpolates_between_samples():
    t = np.array([0.0, 1.0, 2.0, 3.0])
    v = np.array([0.0, 0.5, 1.5, 3.0])
    tc, idx = first_crossing(t, v, 1.0)
    assert tc == pytest.approx(1.5)
    assert idx == 2
    assert first_crossing(t, v, 5.0) is None
    # NaN samples are skipped, the crossing interpolated across them
    v2 = np.array([0.0, np.nan, np.nan, 3.0])
    assert first_crossing(t, v2, 1.5)[0] == pytest.approx(1.5)


def test_straight_line_with_lateral_drift():
    # Y = v t, X = a Y: time to 2 m is 2/v; |X| at the stations Y = 0, 0.25, ..., 2 averages a * 1.0 m
    v, a = 0.1, 0.05
    t = np.arange(0, 40, 1 / 15)
    y = v * t
    x = a * y
    sc = score_straight(t, x, y)
    assert sc.completed
    assert sc.time_s == pytest.approx(20.0, abs=1e-9)
    assert sc.mae_x_m == pytest.approx(a * 1.0, abs=1e-9)
    assert len(sc.stations) == 9
    assert sc.stations[0] == (0.0, 0.0, 0.0)
    assert sc.radius_m is None


def test_straight_first_reach_counts_not_later_ones():
    # the robot passes Y = 1 m at X = 0.2, backs off and passes again at X = 0: the first crossing counts
    t = np.linspace(0, 30, 3001)
    y = np.interp(t, [0, 10, 12, 30], [0, 1.2, 0.8, 2.5])
    x = np.where(t < 11, 0.2, 0.0)
    sc = score_straight(t, x, y)
    xs = dict((round(s[0], 2), s[2]) for s in sc.stations)
    assert xs[1.0] == pytest.approx(0.2)
    assert xs[2.0] == pytest.approx(0.0)


def test_straight_never_finishing_is_capped_at_60_s():
    t = np.arange(0, 65, 0.1)
    y = 0.02 * t  # 1.2 m after 60 s
    x = -0.1 * y
    sc = score_straight(t, x, y)
    assert not sc.completed
    assert sc.time_s == CAP_S
    levels = [s[0] for s in sc.stations]
    assert levels == [0.0, 0.25, 0.5, 0.75, 1.0]
    assert sc.mae_x_m == pytest.approx(0.1 * np.mean(levels))
    # a late crossing after the cap does not count
    y_late = np.where(t < 61, 0.02 * t, 2.5)
    assert not score_straight(t, x, y_late).completed


def test_straight_video_too_short_to_decide():
    t = np.arange(0, 30, 0.1)
    with pytest.raises(UndecidedError):
        score_straight(t, 0 * t, 0.01 * t)
    # a cap reached within one frame is enough
    t2 = np.arange(0, 60.0 - 0.05, 0.1)
    assert not score_straight(t2, 0 * t2, 0.01 * t2, frame_s=0.1).completed


def _circle(radius, omega, t, direction=1):
    yaw = direction * omega * t
    x = -direction * radius + direction * radius * np.cos(yaw)
    y = direction * radius * np.sin(yaw)
    return x, y, yaw


@pytest.mark.parametrize("direction", [1, -1])
def test_turn_time_and_radius(direction):
    omega = 2 * np.pi / 25.0
    t = np.arange(0, 40, 1 / 15)
    x, y, yaw = _circle(0.08, omega, t, direction)
    sc = score_turn(t, x, y, yaw)
    assert sc.completed
    assert sc.time_s == pytest.approx(25.0, abs=1e-6)
    assert sc.radius_m == pytest.approx(0.08, abs=1e-9)
    assert sc.circle_center[0] == pytest.approx(-direction * 0.08, abs=1e-9)


def test_turn_never_finishing_fits_over_the_whole_60_s():
    omega = 2 * np.pi / 100.0  # 216 degrees in 60 s
    t = np.arange(0, 62, 0.1)
    x, y, yaw = _circle(0.3, omega, t)
    sc = score_turn(t, x, y, yaw)
    assert not sc.completed and sc.time_s == CAP_S
    assert sc.radius_m == pytest.approx(0.3, abs=1e-9)


def test_geometric_circle_fit_beats_algebraic_on_a_noisy_short_arc():
    # Kasa's algebraic fit is biased low on a short noisy arc; the geometric refinement is not
    rng = np.random.default_rng(0)
    errs_geo, errs_kasa = [], []
    for _ in range(30):
        a = np.linspace(0, 1.2, 200)
        x = 0.5 * np.cos(a) + rng.normal(0, 0.02, a.size)
        y = 0.5 * np.sin(a) + rng.normal(0, 0.02, a.size)
        errs_geo.append(fit_circle(x, y)[2] - 0.5)
        u, v = x - x.mean(), y - y.mean()
        sol = np.linalg.lstsq(np.column_stack([u, v, np.ones_like(u)]), -(u**2 + v**2), rcond=None)[0]
        errs_kasa.append(np.sqrt(sol[0] ** 2 / 4 + sol[1] ** 2 / 4 - sol[2]) - 0.5)
    assert abs(np.mean(errs_geo)) < abs(np.mean(errs_kasa))
    assert np.mean(errs_kasa) < -0.01


def test_turn_needs_heading():
    t = np.arange(0, 10, 0.1)
    with pytest.raises(DataError):
        score_turn(t, t, t, np.full_like(t, np.nan))
    with pytest.raises(DataError):
        fit_circle(np.array([0.0, 1.0]), np.array([0.0, 1.0]))


def test_circle_fit_without_a_circle_is_an_error_not_a_radius():
    # points on a line: the geometric fit runs off to a huge radius and stops there "successfully";
    # that is no circle, so it is a ConvergenceError naming what failed, never a radius
    s = np.linspace(0.0, 2.0, 40)
    for x, y in ((s, np.zeros_like(s)), (0.3 + 0.6 * s, -0.1 + 0.8 * s)):
        with pytest.raises(ConvergenceError, match="circle fit to 40 positions found no circle") as exc:
            fit_circle(x, y)
        assert "lie on a line" in exc.value.format() and "\n" not in exc.value.format()
    # a robot that sits still (or rocks between two spots) gives too few distinct positions
    with pytest.raises(DataError, match="only 1 distinct positions among 30"):
        fit_circle(np.full(30, 0.7), np.full(30, 1.2))
    with pytest.raises(DataError, match="only 2 distinct positions among 6"):
        fit_circle(np.array([0.0, 0.1] * 3), np.array([0.0, 0.2] * 3))
    # a gentle arc well inside the bound still fits: radius 50 m over a 2 m path (bow 1 cm)
    a = np.linspace(0.0, 2.0 / 50.0, 60)
    cx, cy, r = fit_circle(50.0 * np.cos(a), 50.0 * np.sin(a))
    assert r == pytest.approx(50.0, rel=1e-6) and 50.0 < MAX_RADIUS_PER_EXTENT * 1.0


def test_a_turn_trial_that_swims_straight_scores_60_s_and_no_radius():
    # judged as a turn, a straight swim never reaches 360 degrees and its path has no circle: its time (the
    # 60 s cap, not completed) is a score, its radius is none (an empty cell, as for straight runs), with a note
    t = np.arange(0.0, 61.0, 0.1)
    sc = score_turn(t, np.zeros_like(t), 0.05 * t, np.zeros_like(t))
    assert sc.time_s == CAP_S and not sc.completed
    assert sc.radius_m is None and sc.circle_center is None
    assert any("no radius" in n and "lie on a line" in n for n in sc.notes)
    # a fit that fails otherwise still fails the trial: the trial and its video are named, the class kept
    from pathlib import Path

    from workbench.contract.trials import CameraSpec, TrialSpec
    from workbench.trials.trial import _fail

    spec = TrialSpec("ef-turn-1", "turn", "EF", 1, Path("videos/ef-turn-1.mp4"), 0.5, CameraSpec((), ()))
    err = _fail(spec, ConvergenceError("the circle fit to 12 positions did not converge (max iterations)"))
    assert type(err) is ConvergenceError
    assert err.format().startswith("videos/ef-turn-1.mp4, trial ef-turn-1: the circle fit to ")


def test_dispatch_and_unknown_task():
    t = np.arange(0, 30, 0.1)
    assert score_trajectory("straight", t, 0 * t, 0.1 * t, 0 * t).completed
    with pytest.raises(DataError):
        score_trajectory("hover", t, t, t, t)
