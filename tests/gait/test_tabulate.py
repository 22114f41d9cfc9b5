"""Tabulated leg wrenches against direct rollouts: the pieces, and objectives within 1 %."""

from dataclasses import replace

import numpy as np
import pytest
from models import LaggedEF, small_lstm

from workbench.gait.cycles import CycleSource, window_sampler
from workbench.gait.objectives import TaskSpec, objectives
from workbench.gait.space import GaitSpace
from workbench.gait.tabulate import TabulatedLegModel, TabulationSettings
from workbench.hydro.ef import EmpiricalFormula
from workbench.hydro.simulator import DEFAULT_DT_S, simulate

#: objective floors for the relative difference |df| / max(|f|, floor): straight f1 (N s), f2 (rad),
#: f3 (s), turn f1 (m), f2 (rad), f3 (s); docs/gaits.md
FLOORS = np.array([0.05, 0.05, 1.0, 0.1, 0.05, 1.0])
SPECS = (TaskSpec("straight", cap_s=10.0, finish_distance_m=0.4), TaskSpec("turn", cap_s=10.0, target_yaw_deg=30.0))


def _gaits(n, seed):
    return GaitSpace().gaits(GaitSpace().sample(n, np.random.default_rng(seed)))


def _objectives(traj):
    return np.concatenate([objectives(traj, s) for s in SPECS], axis=1)


def _well_conditioned(traj, margin=0.01, window_s=0.5):
    """(B, 6) mask: objectives whose task is finished at a clear pace, or clearly not at all.

    A swim whose progress (distance, or accumulated yaw) lingers near the target (a turn made in
    steps that stops just short of it) moves its finishing time by seconds for a hair's
    difference in the swim; such objectives are compared through the trajectories instead.
    """
    ok = []
    for spec in SPECS:
        progress = traj.y_m if spec.task == "straight" else np.abs(traj.yaw_rad)
        target = spec.finish_distance_m if spec.task == "straight" else np.radians(spec.target_yaw_deg)

        def first(level, progress=progress):
            hit = progress >= level
            return np.where(hit.any(axis=1), traj.t_s[hit.argmax(axis=1)], np.inf)

        t_lo, t_hi = first(target * (1 - margin)), first(target * (1 + margin))
        with np.errstate(invalid="ignore"):   # never reached: inf - inf
            clear = np.isinf(t_lo) | (t_hi - t_lo < window_s)
        ok.append(np.repeat(clear[:, None], 3, axis=1))
    return np.concatenate(ok, axis=1)


def _compare(model, gaits, robot, check=True, **settings):
    direct = simulate(gaits, model, robot, duration_s=10.0)
    tab = TabulatedLegModel(model, gaits, TabulationSettings(mode="always", **settings), sim_dt_s=DEFAULT_DT_S)
    tabulated = simulate(gaits, tab, robot, duration_s=10.0)
    a, b = _objectives(tabulated), _objectives(direct)
    rel = np.abs(a - b) / np.maximum(np.abs(b), FLOORS)
    ok = _well_conditioned(direct)
    pos = np.abs(tabulated.y_m - direct.y_m).max() / np.abs(direct.y_m).max()
    yaw = np.abs(tabulated.yaw_rad - direct.yaw_rad).max()
    print(f"{type(model).__name__}: position error {pos:.2%} of the longest swim, yaw error {yaw:.4f} rad; "
          f"objectives compared: {ok.mean():.0%}")
    if check:
        assert ok.mean() > 0.8, "too many swims creep over the target: pick other test gaits"
        # trajectories agree everywhere, objectives where finishing is well defined
        assert pos < 5e-3 and yaw < 0.01
    return np.where(ok, rel, 0.0), tab, tabulated, direct


def test_tabulated_ef_matches_its_exact_fast_path(robot):
    rel, tab, tabulated, direct = _compare(EmpiricalFormula(), _gaits(12, 1), robot)
    assert tab.stats()["kind"] == "rollout" and tab.stats()["direct_calls"] == 0
    assert rel.max() < 5e-3, rel.max(axis=0)
    np.testing.assert_allclose(tabulated.y_m, direct.y_m, atol=1e-3)


def test_lagged_model_agrees_with_its_direct_rollout(robot):
    """A model with unbounded memory (the EF through a 20 ms lag, the low end of servo lags).

    Swims agree within 0.1 %, times and path lengths within 1 %. The heading and momentum
    objectives are small differences of large numbers (the heading swings every stroke, the
    momentum at the finish oscillates with it): they are held to 3 % (docs/gaits.md).
    """
    rel, tab, tabulated, direct = _compare(LaggedEF(0.02), _gaits(12, 2), robot)
    print("lagged EF: max relative difference per objective", np.round(rel.max(axis=0), 4))
    assert rel[:, [2, 3, 5]].max() < 0.01, rel.max(axis=0)
    assert rel.max() < 0.03, rel.max(axis=0)
    assert np.abs(tabulated.y_m - direct.y_m).max() < 1e-3 * np.abs(direct.y_m).max()
    # the flow-memory profile is the lag's exponential: weights fall by exp(-dt/tau) per tick
    k = tab.flow_kernel
    assert k.sum() == pytest.approx(1.0, abs=1e-6)
    assert k[1] / k[0] == pytest.approx(np.exp(-DEFAULT_DT_S / 0.02), rel=0.1)


def test_the_corrections_matter_for_long_memory(robot):
    """With a 40 ms lag the flow-memory and start-up corrections cut the trajectory error (about threefold)."""
    g = _gaits(12, 2)
    _, _, with_corr, direct = _compare(LaggedEF(0.04), g, robot, check=False)
    _, _, without, _ = _compare(LaggedEF(0.04), g, robot, check=False, flow_memory=False, startup_correction=False)
    err_with = np.abs(with_corr.y_m - direct.y_m).max()
    err_without = np.abs(without.y_m - direct.y_m).max()
    print(f"40 ms lag: largest position error {err_with * 1e3:.2f} mm with the corrections, "
          f"{err_without * 1e3:.2f} mm without")
    assert err_with < err_without / 2


@pytest.mark.slow
@pytest.mark.parametrize("variant", ["ef_residual", "lstm"])
def test_lstm_objectives_within_one_percent(robot, variant):
    """The FED-LSTM code path with random weights: EF + an LSTM memory term, and a bare LSTM
    (whose flow weighting spreads over its whole 16-tick window)."""
    model = small_lstm(hidden=32, residual_scale_n=0.1 if variant == "ef_residual" else 0.2, variant=variant)
    rel, tab, *_ = _compare(model, _gaits(6, 3), robot)
    stats = tab.stats()
    print(f"small {variant} LSTM: max relative difference per objective", np.round(rel.max(axis=0), 4), stats)
    assert stats["kind"] == "window" and stats["direct_calls"] == 0
    assert rel.max() < 0.01, rel.max(axis=0)


def test_window_sampler_reproduces_the_model_on_its_last_tick():
    model = small_lstm()
    sampler = window_sampler(model)
    assert sampler is not None and sampler.seq_len == 16
    g = _gaits(3, 4)
    motion = g.leg_motion(np.arange(40) * DEFAULT_DT_S)
    motion = replace(motion, flow_speed_mps=np.full(motion.shape, 0.07))
    full = model.wrench(motion)
    last = sampler.predict(_tail(motion, 16))
    np.testing.assert_allclose(last, full[:, -1], rtol=1e-5, atol=1e-7)
    assert window_sampler(EmpiricalFormula()) is None
    assert window_sampler(LaggedEF()) is None


def _tail(motion, n):
    return replace(motion, **{k: getattr(motion, k)[:, -n:] for k in (
        "theta_h_deg", "theta_k_deg", "omega_h_dps", "omega_k_dps", "flow_speed_mps", "alpha_h_dps2", "alpha_k_dps2")})


def test_memoryless_model_has_a_unit_flow_kernel():
    src = CycleSource(EmpiricalFormula(), sim_dt_s=DEFAULT_DT_S, phase_samples=48, warmup_s=0.5)
    np.testing.assert_allclose(src.flow_kernel(), [1.0], atol=1e-9)


def test_wrapper_is_faithful_for_other_motions_and_checks_the_batch(robot):
    model = LaggedEF()
    g = _gaits(3, 5)
    tab = TabulatedLegModel(model, g, TabulationSettings(mode="always"), sim_dt_s=DEFAULT_DT_S)
    t = np.arange(50) * DEFAULT_DT_S
    own = g.leg_motion(t)
    other = _gaits(3, 6).leg_motion(t)
    assert tab.is_batch_motion(own) and not tab.is_batch_motion(other)
    assert not tab.is_batch_motion(replace(own, dt_s=own.dt_s * 1.01))
    other = replace(other, flow_speed_mps=np.full(other.shape, 0.1))
    np.testing.assert_array_equal(tab.wrench(other), model.wrench(other))
    assert tab.stats()["direct_calls"] == 1
    # the EF keeps its own exact fast path unless tabulation is forced
    assert not TabulatedLegModel(EmpiricalFormula(), g, TabulationSettings(), sim_dt_s=DEFAULT_DT_S).tabulating


def test_settings_refuse_unknown_keys():
    from workbench.errors import ParamsError

    with pytest.raises(ParamsError, match=r"^g\.yaml, optimize\.tabulation\.flow_step: unknown setting 'flow_step' "
                                          r"\(did you mean 'flow_step_mps'\? allowed: mode, flow_step_mps"):
        TabulationSettings.from_dict({"flow_step": 0.1}, path="g.yaml")
    with pytest.raises(ParamsError, match=r"optimize\.tabulation: tabulation\.interpolation must be one of"):
        TabulationSettings.from_dict({"interpolation": "quintic"})
    with pytest.raises(ValueError):
        TabulationSettings(interpolation="quintic")
