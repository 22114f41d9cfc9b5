"""Stroke sidebands (``evidence_lines.mark_sidebands``): one disturbance, one unexplained line.

A flow tone loads the leg by how fast it moves through the water, so the stroke modulates it and
the motion scan finds lines at f0 +- k f_g (f_g: a run's gait frequency) beside f0 itself; on the
probe campaign a 3 Hz tone came out as nine "unexplained" lines. Rich-truth campaigns, disturbances
planted by the tests' own formulas (``planting.py``); the gait multiples are computed here.
"""

from __future__ import annotations

import battery  # noqa: E402  (tests/diagnose/battery.py: a broken import must fail, not skip)
import planting  # noqa: E402
import pytest


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    return battery.Bench(tmp_path_factory.mktemp("sidebands"), n_sets=4)


def _evidence(bench, folder):
    from workbench.diagnose.chain import Configuration, Lowpass
    from workbench.diagnose.evidence import analyse
    from workbench.diagnose.problem import run_residuals

    runs = run_residuals(bench.problem(folder), Configuration())
    return runs, analyse(runs, lowpass=Lowpass(6.0, 4))


def _unexplained(ev):
    from workbench.diagnose.loop_claims import _unexplained
    from workbench.diagnose.loop_settings import DiagnoseSettings

    return [u for u in _unexplained(ev, [], {}, DiagnoseSettings()) if u.kind == "narrowband"]


def _gait_multiple(d_hz: float, gaits: set[float], tol: float = 0.06) -> bool:
    return any(abs(d_hz - k * g) <= tol for g in gaits for k in (1, 2, 3))


def test_a_flow_tones_stroke_sidebands_are_one_unexplained_line(bench):
    folder = planting.copy_campaign(bench.new_campaign(), bench.root / "tone3",
                                    [planting.flow_tone(3.0, 0.08, seed=5)])
    runs, ev = _evidence(bench, folder)
    gaits = {round(r.freq, 6) for r in runs}
    near = [p for p in ev.peaks if abs(p.frequency_hz - 3.0) < 1.9]
    # the motion scan sees the tone and its sidebands a gait frequency away (what made many lines)
    assert len(near) >= 2, ev.peaks
    carriers = [p for p in near if p.sideband_of is None]
    assert len(carriers) == 1 and abs(carriers[0].frequency_hz - 3.0) < 0.05, near
    for p in near:
        if p.sideband_of is not None:
            assert p.sideband_of == carriers[0].frequency_hz
            assert _gait_multiple(abs(p.frequency_hz - 3.0), gaits), (p.frequency_hz, gaits)
    assert any(p.get("sideband_of_hz") for p in ev.summary()["narrowband_peaks"])
    lines = _unexplained(ev)
    assert len(lines) == 1 and abs(lines[0].frequency_hz - 3.0) < 0.05, [u.evidence for u in lines]
    assert "sideband" in lines[0].evidence
    # a tone in the flow: at rest it is there only where water flows
    assert "only where water flows" in lines[0].evidence, lines[0].evidence
    for p in near:
        if p.sideband_of is not None:
            assert f"{p.frequency_hz:.2f}" in lines[0].evidence


def test_two_rig_vibrations_a_gait_frequency_apart_stay_two_lines(bench):
    """A vibration is in every run; a sideband only in the runs whose gait frequency puts it there.

    3.38 and 3.78 Hz: 0.4 Hz apart (a sideband's distance in the runs at 0.4 Hz) and on no gait
    harmonic of the other runs (0.3, 0.5, 0.6 Hz), where each stands on its own. The rest stretches
    (1 s: 2 Hz resolution) cannot part them.
    """

    folder = planting.copy_campaign(bench.new_campaign(), bench.root / "vib-pair", [
        planting.vibration(3.38, {"fx_n": 0.012, "tx_nm": 0.0015}, seed=3),
        planting.vibration(3.78, {"fx_n": 0.012, "tx_nm": 0.0015}, seed=4)])
    runs, ev = _evidence(bench, folder)
    assert _gait_multiple(0.4, {round(r.freq, 6) for r in runs})
    lines = _unexplained(ev)
    for f in (3.38, 3.78):
        assert [u for u in lines if abs(u.frequency_hz - f) < 0.05], (f, [u.evidence for u in lines])
    assert not [u for u in lines if "sideband" in u.evidence], [u.evidence for u in lines]
