"""A rig vibration above the ingest's low-pass cutoff is still reported as a line, at its frequency and channel.

Issue 13 plants structural vibration at 2-8 Hz. The ingest's 6 Hz, order-4 zero-phase low-pass keeps
|H|^2 = 1 / (1 + (8/6)^8) = 0.09 of an 8 Hz vibration's amplitude, and of the noise around it: the
line's ratio to its floor is unchanged. The line scan stopped at 6.5 Hz (``fmax_hz``), so an 8 Hz
vibration went unreported (measured 30 Nov 2026 on the second probe, EF, no reference: 0.02 N in fy,
no line); it now scans to ``lines_fmax_hz`` (9 Hz). Rich-truth campaign, the vibration planted by the
tests' own formula (``planting.vibration``), the evidence of the EF's residual before any effect.
"""

from __future__ import annotations

import dataclasses

import battery  # noqa: E402  (tests/diagnose/battery.py: a broken import must fail, not skip)
import planting  # noqa: E402
import pytest


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    b = battery.Bench(tmp_path_factory.mktemp("lines8"), n_sets=4)
    return b, b.new_campaign()


def _lines(bench, folder, **evidence):
    from workbench.diagnose.chain import Configuration, Lowpass
    from workbench.diagnose.data import prepare
    from workbench.diagnose.evidence import analyse
    from workbench.diagnose.evidence_base import EvidenceSettings
    from workbench.diagnose.problem import Problem, run_residuals
    from workbench.hydro.legmodel import load_leg_model

    problem = Problem(prepare(bench.frame(folder)), load_leg_model("ef"), Lowpass(6.0, 4))
    res = run_residuals(problem, Configuration(), problem.fit(Configuration(), names=[]))
    s = dataclasses.replace(EvidenceSettings(), **evidence)
    return [(p.frequency_hz, p.channels) for p in analyse(res, s, 6.0, lowpass=problem.lowpass).peaks]


@pytest.fixture(scope="module")
def planted(bench):
    b, campaign = bench
    return b, planting.copy_campaign(campaign, b.root / "vib8", [planting.vibration(8.0, {"fy_n": 0.02}, seed=6)])


def test_an_8hz_vibration_is_a_line_in_fy(planted):
    b, folder = planted
    lines = _lines(b, folder)
    assert [c for f, c in lines if abs(f - 8.0) < 0.05] == [["fy_n"]], lines


def test_the_clean_campaign_shows_no_line_past_the_cutoff(bench):
    b, campaign = bench
    lines = _lines(b, campaign)
    assert not [f for f, _ in lines if f > 6.5], lines
