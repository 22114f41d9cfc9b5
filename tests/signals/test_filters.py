"""The zero-phase low-pass (attenuation above cutoff, no phase lag) and the smoothed derivative."""

from __future__ import annotations

import numpy as np
import pytest

from workbench.signals.filters import derivative, frequency_response_db, lowpass, lowpass_sampled

FS = 500.0


def tone(f, t):
    return np.sin(2 * np.pi * f * t)


def test_passband_cutoff_and_stopband():
    t = np.arange(0, 20, 1 / FS)
    gain = {f: np.std(lowpass(tone(f, t), FS)[2000:-2000]) / np.std(tone(f, t)[2000:-2000]) for f in (1, 6, 12, 24, 60)}
    assert gain[1] == pytest.approx(1.0, abs=0.002)                   # the paddling band passes untouched
    assert 20 * np.log10(gain[6]) == pytest.approx(-3.0, abs=0.3)     # -3 dB at the 6 Hz cutoff
    assert 20 * np.log10(gain[12]) < -40                              # two octaves of 8th-order roll-off
    assert 20 * np.log10(gain[24]) < -80
    assert gain[60] < 1e-6                                            # mains pickup and vibration gone


def test_designed_response_matches_the_measured_one():
    db = frequency_response_db(np.array([1.0, 6.0, 12.0]), FS)
    assert db[0] == pytest.approx(0.0, abs=0.05) and db[1] == pytest.approx(-3.0, abs=0.05) and db[2] < -40


def test_zero_phase_keeps_peaks_in_place():
    t = np.arange(0, 10, 1 / FS)
    x = tone(0.6, t) + 0.2 * tone(3.0, t) + 0.1 * tone(40.0, t)
    y = lowpass(x, FS)
    lag = np.argmax(np.correlate(y[1000:-1000], (tone(0.6, t) + 0.2 * tone(3.0, t))[1000:-1000], "full")) - (len(t) - 2001)
    assert lag == 0


def test_custom_cutoff_and_too_slow_sampling():
    t = np.arange(0, 20, 1 / FS)
    assert np.std(lowpass(tone(3, t), FS, cutoff_hz=1.0)[2000:-2000]) < 0.01
    x = tone(1, np.arange(0, 5, 1 / 10.0))
    np.testing.assert_array_equal(lowpass(x, 10.0, cutoff_hz=6.0), x)  # nothing above 6 Hz at 10 Hz sampling


def test_lowpass_on_jittered_samples():
    rng = np.random.default_rng(0)
    t = np.arange(0, 10, 1 / 65) + rng.normal(0, 0.0005, 650)
    y = lowpass_sampled(t, tone(0.5, t) + 0.3 * tone(20.0, t))
    np.testing.assert_allclose(y[50:-50], tone(0.5, t)[50:-50], atol=0.02)


@pytest.mark.parametrize("jitter", [0.0, 0.0005])
def test_derivative_of_a_sinusoid(jitter):
    rng = np.random.default_rng(1)
    t = np.arange(0, 10, 1 / 65) + rng.normal(0, jitter, 650)
    x = 55 * np.sin(2 * np.pi * 0.6 * t)
    d = derivative(t, x, window=7, polyorder=3)
    truth = 55 * 2 * np.pi * 0.6 * np.cos(2 * np.pi * 0.6 * t)
    np.testing.assert_allclose(d[5:-5], truth[5:-5], atol=0.002 * np.abs(truth).max())
