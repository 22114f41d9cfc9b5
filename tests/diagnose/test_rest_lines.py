"""Lines at rest (``evidence.rest_lines``): the rig's own vibration, seen while the leg stands still.

A vibration whose frequency is a gait harmonic of every run (6 Hz is the 10th to 20th harmonic of
0.3-0.6 Hz strokes) cannot be told from the stroke-locked misfit in the moving runs; in the rest
stretch before each run the stroke is not there yet. Rich-truth campaigns (the EF's magnitudes are
wrong there), disturbances planted by the tests' own formulas (``planting.py``).
"""

from __future__ import annotations

import battery  # noqa: E402  (tests/diagnose/battery.py: a broken import must fail, not skip)
import planting  # noqa: E402
import pytest


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    return battery.Bench(tmp_path_factory.mktemp("rest"), n_sets=4)


def _residuals(bench, folder, drop_rest: bool = False):
    from workbench.diagnose.chain import Configuration
    from workbench.diagnose.problem import run_residuals

    return run_residuals(bench.problem(folder, drop_rest=drop_rest), Configuration())


def _lines(runs):
    """Lines at rest through the rigs' 6 Hz, 4th-order low-pass."""
    from workbench.diagnose.chain import Lowpass
    from workbench.diagnose.evidence import rest_lines

    return rest_lines(runs, lowpass=Lowpass(6.0, 4))


def _vibration():
    """A pump's vibration at 6 Hz in fx and tx, its own random phase per run (``planting.vibration``)."""
    return planting.vibration(6.0, {"fx_n": 0.012, "tx_nm": 0.0015}, seed=3)


def test_the_clean_rich_campaign_has_no_line_at_rest(bench):

    runs = _residuals(bench, bench.new_campaign())
    assert sum(r.rest.sum() > 0 for r in runs) >= 6
    assert _lines(runs) == []


def test_a_vibration_on_every_gait_harmonic_is_found_at_rest(bench):
    from workbench.diagnose.chain import Lowpass
    from workbench.diagnose.evidence import analyse, peaks

    folder = planting.copy_campaign(bench.new_campaign(), bench.root / "vib6",
                                    [_vibration()])
    runs = _residuals(bench, folder)
    # in motion the 6 Hz line sits on a harmonic of every run: the moving scan cannot claim it
    assert not [p for p in peaks(runs) if abs(p.frequency_hz - 6.0) < 0.3]
    found = [p for p in _lines(runs) if abs(p.frequency_hz - 6.0) < 0.1]
    assert len(found) == 1, _lines(runs)
    line = found[0]
    assert {"fx_n", "tx_nm"} <= set(line.channels) and not {"fy_n", "fz_n"} & set(line.channels)
    assert line.at_rest and line.ratio["tx_nm"] > 10
    # and the evidence reports it with the lines of the motion
    ev = analyse(runs, lowpass=Lowpass(6.0, 4))
    assert any(p.at_rest and abs(p.frequency_hz - 6.0) < 0.1 for p in ev.peaks)
    assert any(p.get("at_rest") for p in ev.summary()["narrowband_peaks"])
    # in still water too: the rig's own, not the flow's
    assert [p.rest_seen for p in ev.peaks if abs(p.frequency_hz - 6.0) < 0.1] == ["still"]


def test_without_a_rest_stretch_there_is_no_rest_line(bench):

    folder = bench.root / "vib6"
    if not folder.is_dir():
        folder = planting.copy_campaign(bench.new_campaign(), folder,
                                        [_vibration()])
    assert _lines(_residuals(bench, folder, drop_rest=True)) == []


def test_a_flow_tone_is_at_rest_only_where_the_flow_runs(bench):
    """A tone on the flow speed loads the standing leg too, but only where water flows."""

    folder = planting.copy_campaign(bench.new_campaign(), bench.root / "tone3",
                                    [planting.flow_tone(3.0, 0.08, seed=5)])
    runs = _residuals(bench, folder)
    flowing = [r for r in runs if abs(r.flow) > 1e-9]
    still = [r for r in runs if abs(r.flow) <= 1e-9]
    assert any(abs(p.frequency_hz - 3.0) < 0.1 for p in _lines(flowing)), _lines(flowing)
    assert not [p for p in _lines(still) if abs(p.frequency_hz - 3.0) < 0.5]
    # and the evidence says so of its line: at rest only where water flows
    from workbench.diagnose.chain import Lowpass
    from workbench.diagnose.evidence import analyse

    ev = analyse(runs, lowpass=Lowpass(6.0, 4))
    line = [p for p in ev.peaks if abs(p.frequency_hz - 3.0) < 0.1 and p.sideband_of is None]
    assert [p.rest_seen for p in line] == ["flow"], ev.peaks
    assert any(q.get("seen_at_rest") == "flow" for q in ev.summary()["narrowband_peaks"])


def test_a_tone_below_the_rest_resolution_leaves_no_line_at_its_edge(bench):
    """A 1 s rest resolves 1 Hz: a 1 Hz tone's lobe spreads to 3 Hz, and must not pose as a 2 Hz line."""

    folder = planting.copy_campaign(bench.new_campaign(), bench.root / "tone1",
                                    [planting.flow_tone(1.0, 0.03, seed=1)])
    runs = [r for r in _residuals(bench, folder) if abs(r.flow) > 1e-9]
    assert _lines(runs) == []
