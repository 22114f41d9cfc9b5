"""A crosstalk entry with a negligible band (option ``floor``) is claimed only when its interval clears it.

A lab that knows its load cell's calibration accuracy can refuse entries below it (a 0.0067
fz-from-fy entry beside a 60 ms servo dead time on the demo campaign, interval 0.0041-0.0093, is
what the servo's remainder leaves). The default is 0 (a planted 1 % crosstalk sits no clearer of
0.005). The numbers here are the test's own.
"""

from __future__ import annotations

from workbench.diagnose.library import make_effect
from workbench.diagnose.loop_claims import _claim_faults
from workbench.diagnose.loop_results import EffectReport
from workbench.diagnose.loop_settings import DiagnoseSettings
from workbench.diagnose.selection_claims import magnitude_intervals


def _report(x: float, se: float) -> EffectReport:
    return EffectReport("loadcell_crosstalk", ["fz_n"], {"x_fz_fy": x}, {"x_fz_fy": se}, "", 0.0, {}, {}, [])


def test_an_entry_clear_of_zero_but_not_of_the_band_is_not_claimed():
    assert make_effect("loadcell_crosstalk").negligible_of("x_fz_fy") == 0.0  # the default: zero itself
    xt = make_effect("loadcell_crosstalk").from_options({"floor": 0.005})
    assert xt.negligible_of("x_fz_fy") == 0.005
    # clear of zero (0.0067 - 1.96 * 0.0013 = 0.0042 > 0) but inside the band: refused
    why = _claim_faults(_report(0.0067, 0.0013), xt, DiagnoseSettings())
    assert why is not None and "negligible band" in why and "x_fz_fy" in why
    # a 1 % entry measured to 0.1 % clears it: claimed; so does a negative one
    assert _claim_faults(_report(0.010, 0.001), xt, DiagnoseSettings()) is None
    assert _claim_faults(_report(-0.010, 0.001), xt, DiagnoseSettings()) is None


def test_the_band_is_the_effects_own_option_and_other_effects_keep_zero():
    xt = make_effect("loadcell_crosstalk")
    assert _claim_faults(_report(0.0067, 0.0013), xt, DiagnoseSettings()) is None
    assert make_effect("loadcell_crosstalk").from_options({"floor": 0.002}).negligible_of("x_ty_tx") == 0.002
    # a torque read from a force is a lever arm (m), a force from a torque a share per metre: no share floor
    assert make_effect("loadcell_crosstalk").from_options({"floor": 0.002}).negligible_of("x_tx_fz") == 0.0
    assert make_effect("loadcell_crosstalk").from_options({"floor": 0.002}).negligible_of("x_fz_tx") == 0.0
    drift = make_effect("sensor_drift")
    assert drift.negligible_of("rate_fz_n_per_s") == 0.0
    # without a band the interval test is the plain one: zero inside or not
    assert magnitude_intervals({"a": 0.0067}, {"a": 0.0013}, 1.96, ()) == {"a": False}
    assert magnitude_intervals({"a": 0.0067}, {"a": 0.0013}, 1.96, (), lambda k: 0.005) == {"a": True}


def test_a_lab_sets_the_band_in_the_pipeline_files_library_options():
    from workbench.diagnose.library import default_library

    lib = default_library(["loadcell_crosstalk", "sensor_drift"], options={"loadcell_crosstalk": {"floor": 0.005}})
    xt = next(e for e in lib if e.name == "loadcell_crosstalk")
    assert xt.negligible_of("x_fz_fy") == 0.005 and xt.options()["floor"] == 0.005
    # the configured copy a diagnosis fits keeps it
    import numpy as np

    rng = np.random.default_rng(0)
    pred = rng.normal(size=(200, 6))
    assert xt.configured(pred, np.ones(200, bool)).negligible_of("x_fy_fz") == 0.005


def test_a_lever_arm_band_applies_to_torques_read_from_forces_only():
    """``lever_floor`` (m): a ty-from-fz lever of 0.37 mm (interval 0.07-0.66 mm; the EF's misfit on
    campaigns without still-water runs) is refused with a 1 mm band, a 20 mm one is claimed."""
    xt = make_effect("loadcell_crosstalk").from_options({"lever_floor": 0.001})
    assert xt.negligible_of("x_ty_fz") == 0.001 and xt.negligible_of("x_tx_fy") == 0.001
    assert xt.negligible_of("x_fz_fy") == 0.0 and xt.negligible_of("x_fz_ty") == 0.0  # shares keep theirs
    assert make_effect("loadcell_crosstalk").negligible_of("x_ty_fz") == 0.0  # the default: zero itself

    def report(x, se):
        return EffectReport("loadcell_crosstalk", ["ty_nm"], {"x_ty_fz": x}, {"x_ty_fz": se}, "", 0.0, {}, {}, [])

    why = _claim_faults(report(-0.00037, 0.00015), xt, DiagnoseSettings())
    assert why is not None and "negligible band" in why and "x_ty_fz" in why
    assert _claim_faults(report(0.02, 0.0005), xt, DiagnoseSettings()) is None
    assert _claim_faults(report(-0.00037, 0.00015), make_effect("loadcell_crosstalk"), DiagnoseSettings()) is None
    # the configured copy a diagnosis fits keeps the band
    import numpy as np

    pred = np.random.default_rng(1).normal(size=(200, 6))
    assert xt.configured(pred, np.ones(200, bool)).negligible_of("x_tz_fx") == 0.001
