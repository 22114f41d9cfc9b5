"""A flow tone without a reference (issue 13): the measured flow sensitivity and the stroke-free tone columns.

Forces are written here with formulas of the test's own (a quadratic in the flow speed whose
coefficients swing with the stroke), not with the library's or the virtual lab's code.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

DT = 1 / 65


def _runset(params: list[dict], flows: list[float], t: np.ndarray, y: np.ndarray, ids: list[str]):
    b = len(flows)
    return SimpleNamespace(shape=(b, len(t)), params=params, valid=np.ones((b, len(t)), bool), run_ids=tuple(ids),
                           flow=np.array(flows), time_s=np.tile(t, (b, 1)), y=y)


def _force(u: float, t: np.ndarray, f_gait: float) -> np.ndarray:
    """F = a(t) U^2 + b(t) U + c(t) per channel, with stroke-locked a, b, c."""
    w = 2 * np.pi * f_gait * t
    a = np.stack([np.sin(w + k) * (1 + 0.3 * k) for k in range(6)], axis=-1)
    b = np.stack([0.2 * np.cos(2 * w + k) for k in range(6)], axis=-1)
    c = np.stack([0.05 * np.sin(3 * w - k) for k in range(6)], axis=-1)
    return a * u * u + b * u + c


def test_measured_sensitivity_is_u_df_du_of_the_readings():
    from workbench.diagnose.flowsens import measured_sensitivity

    t = np.arange(0, 10, DT)
    speeds = [0.0, 0.12, 0.25]
    p1 = dict(theta_h_min_deg=10.0, theta_h_max_deg=-100.0, theta_k_min_deg=80.0, theta_k_max_deg=-20.0,
              frequency_hz=0.4, phi_rad=1.0, alpha_rad=0.0)
    p2 = dict(p1, frequency_hz=0.5)
    y = np.stack([_force(u, t, 0.4) for u in speeds])
    # the second set is run at two speeds only: its runs are left to the model's sensitivity
    y2 = np.stack([_force(u, t, 0.5) for u in speeds[:2]])
    # the runs arrive in two batches, the sets mixed (the sensitivity is gathered over the campaign)
    rs_a = _runset([p1, p2], [0.12, 0.12], t, np.stack([y[1], y2[1]]), ["a12", "b12"])
    rs_b = _runset([p1, p1, p2], [0.0, 0.25, 0.0], t, np.stack([y[0], y[2], y2[0]]), ["a00", "a25", "b00"])
    got = measured_sensitivity([rs_a, rs_b])
    assert set(got) == {"a00", "a12", "a25"}
    w = 2 * np.pi * 0.4 * t
    for rid, u in (("a12", 0.12), ("a25", 0.25)):
        tt, g = got[rid]
        a = np.stack([np.sin(w + k) * (1 + 0.3 * k) for k in range(6)], axis=-1)
        b = np.stack([0.2 * np.cos(2 * w + k) for k in range(6)], axis=-1)
        assert np.allclose(g, u * (2 * a * u + b), atol=1e-9)
    assert np.allclose(got["a00"][1], 0.0)


def test_stroke_free_columns_keep_the_tone_and_drop_the_stroke():
    """g sin(2 pi f t) keeps what the stroke cannot make; where f is a gait harmonic nothing is left."""
    from workbench.diagnose.flowsens import without_stroke

    t = np.arange(0, 4 / 0.3, DT)
    rng = np.random.default_rng(4)
    g = _force(0.2, t, 0.3)                                # stroke-locked flow sensitivity
    mask = np.ones(len(t), bool)
    mask[:30] = mask[-30:] = False                         # the trimmed ends
    for f_gait, tone_hz, left in ((0.3, 2.0, (0.5, 1.01)), (0.5, 2.0, (0.0, 0.02))):
        gg = _force(0.2, t, f_gait)
        col = (gg * np.sin(2 * np.pi * tone_hz * t + 0.7)[:, None])[None]
        out = without_stroke(col, t[None], mask[None], np.array([f_gait]))[0]
        share = np.sum(out[mask] ** 2) / np.sum(col[0][mask] ** 2)
        assert left[0] <= share <= left[1], (f_gait, share)
    # a stroke-locked misfit (any periodic waveform of the gait) is removed entirely
    misfit = np.stack([np.sin(2 * np.pi * 0.3 * k * t + rng.uniform(0, 6)) for k in range(1, 7)], axis=-1) + g
    out = without_stroke(misfit[None], t[None], mask[None], np.array([0.3]))[0]
    assert np.sqrt(np.mean(out[mask] ** 2)) < 1e-6 * np.sqrt(np.mean(misfit[mask] ** 2))


def test_options_round_trip_and_bad_values_are_refused():
    from workbench.diagnose.effects.rig import FlowUnsteadiness
    from workbench.errors import ModelError

    e = FlowUnsteadiness.from_options({"sensitivity": "model", "stroke_free": False})
    assert e.options() == {"sensitivity": "model", "stroke_free": False}
    assert FlowUnsteadiness().options() == {"sensitivity": "measured", "stroke_free": False}
    with pytest.raises(ModelError, match="sensitivity"):
        FlowUnsteadiness(sensitivity="guess")
    with pytest.raises(ModelError, match="stroke_free"):
        FlowUnsteadiness(stroke_free="sometimes")
