"""Issue 13's battery: effects planted into raw rich-truth campaigns by formulas of the test's own.

The virtual lab makes two measurements of the same rig (rich truth: physics the EF lacks), a
reference and a new campaign (other noise, biases, drifts and clocks). ``planting.py`` edits
copies of the new campaign's CSV files (delayed forces for a dead-time servo, crosstalk between
channels, a thermal drift, a mount mode, an angle-dependent static torque, a flow tone whose
force is measured across the flow speeds, a narrowband vibration), then the copies go through
``workbench ingest`` and ``diagnose --reference``. ``benchmarks/diagnose_battery.py`` prints the
confusion table for every base and mode; this test holds the done-when criteria for the EF base
against a reference.
"""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = pytest.mark.slow

import battery  # noqa: E402  (tests/diagnose/battery.py: a broken import must fail, not skip)


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    return battery.Bench(tmp_path_factory.mktemp("battery"), n_sets=12)


def test_clean_campaign_against_its_reference_claims_nothing(bench):
    d = bench.clean("ef", True)
    assert [e.name for e in d.effects] == []
    assert d.reference["matched_runs"] == 36
    # the EF's misfit was learned, not diagnosed: what is left is the rig's noise
    assert not [u for u in d.unexplained if u.kind == "gait_locked"]


def test_claims_without_reference_have_intervals_clear_of_zero(bench):
    from workbench.diagnose.selection import magnitude_intervals

    d = bench.clean("ef", False)
    for e in d.effects:
        spans = magnitude_intervals(e.params, e.stderr)
        assert spans and not all(spans.values()), (e.name, e.params, e.stderr)
        if e.name == "structural_resonance":
            assert e.params["zeta"] <= 0.3
    # the rich truth has no servo: the look-ahead path that takes a delay must not win on it
    assert "servo_lag" not in [e.name for e in d.effects]


#: every case is held to the criteria (the mount mode's damping, the crosstalk beside it and the 60 ms
#: dead time beside a drift were expected failures until the reference stopped carrying its noise);
#: (a first-order-only servo_lag left a 60 ms dead time's remnant to one light mode; with the dead
#: time in servo_lag nothing extra was claimed on the three servo cases)
CASES = [pytest.param(c, id=c.name) for c in battery.all_cases(with_reference=True)]


@pytest.mark.parametrize("case", CASES)
def test_planted_effect_is_named_measured_and_removed(case, bench):
    r = bench.run(case, "ef", True)
    for planted, named in r["hits"].items():
        assert named is not None, f"{planted} not named: {r['named']}, unexplained {r['unexplained']}"
    for k, err in r["param_err"].items():
        assert err is not None and err <= 0.2, (k, r["params"])
    assert all(r["lines_ok"]), r["unexplained"]
    if r["hits"]:
        assert r["removed_share"] is not None and r["removed_share"] >= 0.7, r
    # nothing the plant does not explain: at most one extra claim, and never a heavily damped mode
    assert len(r["extra"]) <= 1, r["extra"]
    zeta = r["params"].get("structural_resonance", {}).get("zeta")
    assert zeta is None or zeta <= 0.3
    assert np.isfinite(r["seconds"])


def test_without_reference_the_ef_names_a_servo_dead_time_and_a_drift_beside_the_force_library(bench):
    """No reference, the EF as base: a 60 ms dead time with a 1.5 mN/s fz drift beside it.

    Measured (30 Nov 2026): tau_s 4.7 % off, the drift 0.7 %, 98 % of the planted error removed, no
    extra claim. The dead time was missed while the servo was a first-order lag only (three force
    effects took the delay's misfit, then nothing was significant: held-out error -265 % of the
    planted), and the drift beside it was never found while a delay chosen early was held where the
    force effects' misfit had put it (``SelectionSettings.follow_lookahead``; ``test_servo_noref.py``
    holds the 25 and 40 ms dead times). One diagnosis holds both: the dead time alone adds nothing
    the pair does not test (it was its own 90-second diagnosis until 30 Nov 2026).
    """
    r = bench.run(battery.pair("servo_dead_60ms", "drift_fz_1.5mN_per_s"), "ef", False)
    assert r["hits"] == {"servo_lag": "servo_lag", "sensor_drift": "sensor_drift"}, (r["named"], r["params"])
    assert r["param_err"]["servo_lag.tau_s"] <= 0.2, r["params"]
    assert r["param_err"]["sensor_drift.rate_fz_n_per_s"] <= 0.2, r["params"]
    assert r["removed_share"] is not None and r["removed_share"] >= 0.7, r
    assert len(r["extra"]) <= 1, r["extra"]
    # a delay is not a heavily damped mode
    assert "structural_resonance" not in r["named"], r["named"]


def test_fed_lstm_base_names_a_dead_time_as_servo_lag_not_a_resonance(bench):
    """The issue's case: with the trained FED-LSTM as base, a 60 ms servo dead time was a 3.9 Hz 'resonance'."""
    from pathlib import Path

    # the repository's own model by path: the root conftest points WORKBENCH_HOME at a temporary folder
    model = Path(__file__).resolve().parents[2] / "datasets" / "models" / "fed-lstm"
    if not (model / "model.json").is_file():
        pytest.skip("the trained FED-LSTM (datasets/models/fed-lstm) is made by dvc repro")
    r = bench.run(battery.case("servo_dead_60ms"), str(model), False)
    assert r["hits"]["servo_lag"] == "servo_lag", r["named"]
    assert r["param_err"]["servo_lag.tau_s"] <= 0.2, r["params"]
    assert "structural_resonance" not in r["named"] or r["params"]["structural_resonance"]["zeta"] <= 0.3


@pytest.mark.parametrize("f_n_hz, zeta", [(3.2, 0.12), (6.5, 0.05)])
def test_a_mount_mode_unlike_the_batterys_is_measured(f_n_hz, zeta, bench):
    """Modes of another frequency and damping than the battery's 4.5 Hz, zeta 0.08 (one above the 6 Hz cutoff).

    The mode is planted by the test's own filter; the reference's noise must not bias the
    damping (it did by +34 % before the reference correction was shrunk and the start kept).
    """
    from planting import mode

    c = battery.Case(f"mode_{f_n_hz}hz_zeta_{zeta}", lambda: [mode(f_n_hz, zeta)],
                     {"structural_resonance": {"f_n_hz": f_n_hz, "zeta": zeta}})
    r = bench.run(c, "ef", True)
    assert r["hits"]["structural_resonance"] == "structural_resonance", (r["named"], r["unexplained"])
    assert r["param_err"]["structural_resonance.f_n_hz"] <= 0.02, r["params"]
    assert r["param_err"]["structural_resonance.zeta"] <= 0.2, r["params"]
    assert r["removed_share"] >= 0.7, r
    assert not r["extra"], r["extra"]
