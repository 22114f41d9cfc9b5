"""Done-when tests: the virtual lab plants effects the EF does not declare; the loop must find them.

Real chain: generate_tunnel (truth = the EF, the rig's clocks, noise, per-run bias and drift)
-> ingest_campaign -> diagnose. Each planted campaign shares its seed with the null campaign,
so the rig's noise is the same and ``mse_before - mse_null`` is exactly the error the effect added.
"""

import numpy as np
import pytest

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.diagnose.loop import diagnose
from workbench.hydro.ef import EmpiricalFormula

pytestmark = pytest.mark.slow

#: planted spec -> the parameters that must come back within 20 %
SINGLES = {
    "servo_lag:tau_s=0.04": {"servo_lag": {"tau_s": 0.04}},
    "added_mass_error:delta_kg=0.05": {"added_mass_error": {"delta_kg": 0.05}},
    "drag_coefficient_error:delta_c=0.3": {"drag_coefficient_error": {"delta_c": 0.3}},
    "tunnel_blockage:epsilon=0.08": {"tunnel_blockage": {"epsilon": 0.08}},
    "loadcell_crosstalk:x_fx_fy=0.03": {"loadcell_crosstalk": {"x_fx_fy": 0.03}},
    "leg_weight_buoyancy:net_n=-0.05,arm_m=0.1": {"leg_weight_buoyancy": {"net_n": -0.05, "arm_m": 0.1}},
    "sensor_drift:rate_fz_n_per_s=0.002": {"sensor_drift": {"rate_fz_n_per_s": 0.002}},
    "structural_resonance:f_n_hz=4,zeta=0.1": {"structural_resonance": {"f_n_hz": 4.0, "zeta": 0.1}},
    "flow_unsteadiness:tone_hz=1.3,tone_fraction=0.02,rms_fraction=0":
        {"flow_unsteadiness": {"tone_hz": 1.3, "tone_fraction": 0.02}},
    "circulatory_lag:tau_chords=2": {"circulatory_lag": {"tau_chords": 2.0}},
    "link_drag:cd_d_m=0.01": {"link_drag": {"cd_d_m": 0.01}},
    "lift:cl=0.3": {"lift": {"cl": 0.3}},
}

PAIRS = [
    ("servo_lag:tau_s=0.04", "sensor_drift:rate_fz_n_per_s=0.002"),
    ("drag_coefficient_error:delta_c=0.3", "loadcell_crosstalk:x_fx_fy=0.03"),
    ("structural_resonance:f_n_hz=4,zeta=0.1", "leg_weight_buoyancy:net_n=-0.05,arm_m=0.1"),
    ("circulatory_lag:tau_chords=2", "added_mass_error:delta_kg=0.05"),
]


def _check(d, expected: dict, null):
    found = {e.name: e for e in d.effects}
    assert set(found) == set(expected), f"claimed {sorted(found)}, planted {sorted(expected)}"
    for name, params in expected.items():
        for k, v in params.items():
            got = found[name].params[k]
            assert got is not None and abs(got - v) <= 0.2 * abs(v), f"{name}.{k}: {got} vs planted {v}"
        assert found[name].heldout_mse_reduction > 0
    # the error the effects added is the error above the null campaign (same seed: same rig noise)
    before = np.array([d.mse_before[c] for c in WRENCH_CHANNELS])
    after = np.array([d.mse_after[c] for c in WRENCH_CHANNELS])
    base = np.array([null.mse_before[c] for c in WRENCH_CHANNELS])
    added = before - base
    hit = added > 0.5 * base
    assert hit.any()
    removed = (before - after)[hit] / added[hit]
    assert np.all(removed > 0.75), dict(zip(np.array(WRENCH_CHANNELS)[hit], removed.round(3), strict=False))


@pytest.mark.parametrize("spec", list(SINGLES), ids=[s.split(":")[0] for s in SINGLES])
def test_single_planted_effect_is_named_recovered_and_removed(spec, vl_frames, null_diagnosis):
    d = diagnose(vl_frames((spec,)), EmpiricalFormula(), "ef")
    _check(d, SINGLES[spec], null_diagnosis)
    assert not [u for u in d.unexplained if u.kind == "narrowband"]


@pytest.mark.parametrize("pair", PAIRS, ids=["+".join(s.split(":")[0] for s in p) for p in PAIRS])
def test_planted_pairs_are_both_found(pair, vl_frames, null_diagnosis):
    d = diagnose(vl_frames(pair), EmpiricalFormula(), "ef")
    expected = {}
    for spec in pair:
        expected.update(SINGLES[spec])
    _check(d, expected, null_diagnosis)


def test_nothing_claimed_when_truth_is_the_model_plus_noise(null_diagnosis):
    d = null_diagnosis
    assert d.effects == []
    assert d.unexplained == []
    for c in WRENCH_CHANNELS:
        assert d.mse_after[c] == pytest.approx(d.mse_before[c])


@pytest.mark.parametrize("with_effect", [False, True], ids=["alone", "beside-servo-lag"])
def test_disturbance_outside_the_library_is_unexplained_not_misnamed(with_effect, vl_frames):
    specs = ("electrical_pickup:f_hz=2.7,amplitude_n=0.01,channels=fy_n+fz_n",)
    if with_effect:
        specs = ("servo_lag:tau_s=0.04",) + specs
    d = diagnose(vl_frames(specs), EmpiricalFormula(), "ef")
    assert [e.name for e in d.effects] == (["servo_lag"] if with_effect else [])
    lines = [u for u in d.unexplained if u.kind == "narrowband"]
    assert len(lines) == 1
    assert lines[0].frequency_hz == pytest.approx(2.7, abs=0.05)
    assert {"fy_n", "fz_n"} <= set(lines[0].channels)
    assert "fx_n" not in lines[0].channels
