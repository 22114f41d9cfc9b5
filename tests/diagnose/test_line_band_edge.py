"""A line is located inside the scanned band, not made of the skirt of something above it.

``evidence_lines.line_scan`` feeds ``find_peaks`` and its running-median floor. The residuals are
made here: white noise in every channel, and in tz a narrowband process at 6.7-7.3 Hz (noise
through a band-pass of the test's own), above the band's 6.5 Hz. Cut at 6.5 Hz, the floor at the
band's last bin saw only the quieter frequencies below it, and the process's skirt read as "a line
at 6.50 Hz" (as a FED-LSTM's residual rising to 8.1 Hz did on a clean demo copy).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy import signal

from workbench.diagnose.evidence_base import EvidenceSettings
from workbench.diagnose.evidence_lines import find_peaks, line_scan, spectral_floor

DT = 1 / 65.0


def _residuals(line_hz: float | None = None, process_hz: tuple[float, float] = (6.7, 7.3)):
    rng = np.random.default_rng(5)
    sos = signal.butter(2, list(process_hz), btype="bandpass", fs=1 / DT, output="sos")
    runs, parts = [], []
    for _ in range(24):
        n = int(20 / DT)
        e = 0.001 * rng.standard_normal((n, 6))
        e[:, 5] += 0.02 * signal.sosfilt(sos, rng.standard_normal(n + 2000))[2000:]
        if line_hz is not None:  # a rig vibration in tx, its own phase per run
            e[:, 3] += 0.002 * np.sin(2 * np.pi * line_hz * DT * np.arange(n) + rng.uniform(0, 2 * np.pi))
        runs.append(SimpleNamespace(dt_s=DT))
        parts.append(e)
    return runs, parts


def _lines(runs, parts, fmax_hz: float = 6.5):
    s = EvidenceSettings(fmax_hz=fmax_hz)
    freqs, scan, dof = line_scan(runs, parts, s)
    return [(round(p.frequency_hz, 2), p.channels)
            for p in find_peaks(freqs, scan, spectral_floor(freqs, scan, s.floor_window_hz), dof, s)]


def test_the_skirt_of_a_process_above_the_band_is_no_line_at_its_edge():
    runs, parts = _residuals()
    assert _lines(runs, parts) == []
    # the floor at the band's end is two-sided: the scan reaches half a floor window past it
    freqs, _, _ = line_scan(runs, parts, EvidenceSettings())
    assert freqs[-1] > 6.5 + 0.4 * EvidenceSettings().floor_window_hz


def test_a_line_inside_is_found_and_the_process_where_it_is_when_the_band_reaches_it():
    runs, parts = _residuals(line_hz=6.0)
    found = _lines(runs, parts)
    assert [c for f, c in found if abs(f - 6.0) < 0.03] == [["tx_nm"]], found
    assert not [f for f, c in found if "tz_nm" in c], found
    wide = _lines(runs, parts, fmax_hz=9.0)
    assert [f for f, c in wide if "tz_nm" in c and 6.7 <= f <= 7.3], wide



def test_a_process_rising_past_the_edge_is_no_line_and_is_found_where_it_is_in_a_wider_band():
    """A narrowband process at 6.55-6.75 Hz, just above the band: the band's top bins sit on its rising
    flank. Without the check that a line's best bin is a local maximum (it must not rise on into the bins
    past the edge) this read as a line at 6.97 Hz, outside the band (the parabola through the flank's
    top bins extrapolates); the line scan's own band (``lines_fmax_hz``, 9 Hz) finds the process at its
    centre."""
    runs, parts = _residuals(process_hz=(6.55, 6.75))
    assert _lines(runs, parts) == []
    wide = _lines(runs, parts, fmax_hz=EvidenceSettings().lines_fmax_hz)
    assert [f for f, c in wide if "tz_nm" in c and 6.55 <= f <= 6.75], wide
