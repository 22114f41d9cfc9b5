"""A line a flow tone was acceptable at stays a candidate while the residual still shows it.

The tone is tried at the ``max_peaks`` strongest residual lines; beside an out-of-library vibration
a tone's own line fell to third after five rounds in which the tone was acceptable but force
effects won, and the tone was never tried again. The peaks here are the test's own.
"""

from __future__ import annotations

from types import SimpleNamespace

from workbench.diagnose.selection import _keep_lines, _Path
from workbench.diagnose.selection_candidates import lines_to_try
from workbench.diagnose.selection_records import SelectionSettings


def _peak(f: float, ratio: float):
    return SimpleNamespace(frequency_hz=f, ratio={"fy_n": ratio})


def test_a_kept_line_below_the_strongest_is_tried_while_the_residual_shows_it():
    s = SelectionSettings(max_peaks=2)
    peaks = [_peak(3.3, 40.0), _peak(2.2, 9.0), _peak(4.0, 6.0), _peak(5.1, 4.0)]
    assert [p.frequency_hz for p in lines_to_try(s, peaks)] == [3.3, 2.2]
    # the tone was acceptable at 4.002 Hz: its line (within tone_window_hz) is tried as well
    assert [p.frequency_hz for p in lines_to_try(s, peaks, [4.002])] == [3.3, 2.2, 4.0]
    # a kept line among the strongest is not tried twice; one the residual no longer shows is not tried
    assert [p.frequency_hz for p in lines_to_try(s, peaks, [3.31, 7.0])] == [3.3, 2.2]


def test_the_path_keeps_each_acceptable_lines_frequency_once():
    from workbench.diagnose.library import make_effect

    tone, drift = make_effect("flow_unsteadiness"), make_effect("sensor_drift")
    from workbench.diagnose.chain import Configuration

    path = _Path(Configuration(), [], None, {}, [], [], {})

    def cand(effect, ok, nl):
        return SimpleNamespace(ok=ok, partner=None, effect=effect, active=SimpleNamespace(nl=nl))

    _keep_lines(path, [cand(tone, True, {"tone_hz": 4.0}), cand(tone, False, {"tone_hz": 3.4}),
                       cand(drift, True, {})])
    _keep_lines(path, [cand(tone, True, {"tone_hz": 4.0})])
    assert path.lines == {"flow_unsteadiness": [4.0]}
    assert path.copy().lines == path.lines and path.copy().lines is not path.lines
