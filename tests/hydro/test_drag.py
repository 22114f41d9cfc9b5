"""Body drag fit: plateau detection, run means, weighted fit, recovery of planted laws, flags, drag.json."""

import json
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from towing_fixture import PAPER, carriage_profile, towing_frame

from workbench.errors import ContractError, DataError, ParamsError
from workbench.hydro.drag import DragFitSettings, PlateauSettings, fit_drag, mean_sem, steady_window
from workbench.project import load_params


@pytest.fixture(scope="module")
def paper_fit():
    return fit_drag(towing_frame(repeats=2, seed=1))


def test_recovers_the_papers_coefficients_within_their_standard_errors(paper_fit):
    for h in paper_fit.headings():
        true = np.array(PAPER[h.heading])
        est, se = np.array(h.coefficients), np.array(h.stderr)
        assert np.all(np.abs(est - true) < 3 * se), (h.heading, est, se)
        assert np.all(se < 0.05 * np.abs(true).max())  # and the errors are informative
        assert h.r2 > 0.999 and len(h.points) == 12 and h.n_speeds == 6
        lo, hi = h.band(np.array([0.2]))
        assert lo[0] < np.polyval(true, 0.2) < hi[0]
    # the paper's forward intercept is drag at rest: flagged
    assert any(f.startswith("drag at rest") for f in paper_fit.forward.flags)


def test_plateau_excludes_acceleration_and_trims_the_ends():
    t, x, v, a = carriage_profile(0.2)
    rng = np.random.default_rng(0)
    noisy = v + rng.normal(0, 0.002, v.size)
    noisy[700] += 0.2  # a glitch in the speed log
    window, v_ref, why = steady_window(t, noisy, PlateauSettings())
    assert why == "" and abs(v_ref - 0.2) < 0.002
    cruise = np.flatnonzero(a == 0)
    t_acc_end = 1.0 + 0.2 / 0.25
    assert t[window][0] >= t_acc_end + 0.5 - 0.02
    t_dec_start = t[cruise[cruise > 200][0]] + (3.0 - 0.2**2 / 0.25) / 0.2
    assert t[window][-1] <= t_dec_start - 0.2 + 0.02
    assert t[window][-1] - t[window][0] > 0.9 * ((3.0 - 0.16) / 0.2 - 0.7)
    # a carriage that never moves, and a tow too short to settle
    assert steady_window(t, np.zeros_like(t))[0] is None
    short, _, why = steady_window(t, noisy, PlateauSettings(min_duration_s=60.0))
    assert short is None and "shorter than" in why


def test_runs_without_a_plateau_are_skipped_and_reported():
    frame = towing_frame(speeds=(0.1, 0.2, 0.3))
    still = frame.filter(pl.col("run_id") == "t001").with_columns(pl.lit(0.0).alias("speed_mps"),
                                                                 pl.lit("t999").alias("run_id"))
    fit = fit_drag(pl.concat([frame, still]))
    assert fit.skipped == (("t999", "the carriage never moved"),)
    assert any(s["run_id"] == "t999" for s in fit.to_json()["skipped_runs"])


def test_headings_from_the_manifest_when_the_frame_has_none():
    frame = towing_frame(speeds=(0.1, 0.2, 0.3, 0.35), heading_column=False)
    headings = {f"t{k:03d}": ("forward" if k <= 4 else "lateral") for k in range(1, 9)}
    fit = fit_drag(frame, headings=headings)
    assert len(fit.forward.points) == 4 and len(fit.lateral.points) == 4
    with pytest.raises(DataError, match="heading"):
        fit_drag(frame)


def test_too_few_speeds_is_an_error():
    with pytest.raises(DataError, match="at least 3 speeds"):
        fit_drag(towing_frame(speeds=(0.1, 0.3), repeats=3))


@pytest.mark.parametrize("coeffs,flag", [
    ({"forward": (-6.0, 6.0, 0.0), "lateral": PAPER["lateral"]}, "negative quadratic term"),
    ({"forward": (10.0, 0.0, -0.3), "lateral": PAPER["lateral"]}, "thrust at rest"),
    ({"forward": (-10.0, 0.0, 0.0), "lateral": PAPER["lateral"]}, "drag is negative"),
])
def test_doubtful_fits_are_flagged(coeffs, flag):
    fit = fit_drag(towing_frame(coeffs=coeffs))
    assert any(f.startswith(flag) for f in fit.forward.flags), fit.forward.flags
    assert not any(f.startswith(flag) for f in fit.lateral.flags)


def test_scatter_and_few_speeds_are_flagged():
    frame = towing_frame(speeds=(0.1, 0.2, 0.3, 0.35), repeats=2)
    # one run's drag 0.5 N high while towed: run-to-run scatter far beyond each run's own noise
    frame = frame.with_columns(pl.when((pl.col("run_id") == "t002") & (pl.col("speed_mps") > 0.02))
                               .then(pl.col("fy_n") - 0.5)
                               .otherwise(pl.col("fy_n")).alias("fy_n"))
    fit = fit_drag(frame)
    flags = " ".join(fit.forward.flags)
    assert "few speeds" in flags and "scatter between runs" in flags and "poor fit" in flags
    assert fit.forward.chi2_red > 100 and fit.lateral.chi2_red < 4


def test_ordinary_least_squares_and_tare():
    frame = towing_frame(speeds=(0.1, 0.15, 0.2, 0.25, 0.3, 0.35))
    ols = fit_drag(frame, params=DragFitSettings(weighting="none"))
    for h in ols.headings():
        assert np.all(np.abs(np.array(h.coefficients) - PAPER[h.heading]) < 3 * np.array(h.stderr))
    # a load-cell zero offset of +0.05 N drifting 2 mN/s on fy: taring removes it (read at rest before and
    # after each tow, interpolated in time), otherwise it shifts the intercept
    shifted = frame.with_columns((pl.col("fy_n") + 0.05 + 0.002 * (pl.col("time_s") - 10.0)).alias("fy_n"))
    raw = fit_drag(shifted, params=DragFitSettings(tare=False))
    tared = fit_drag(shifted)  # taring is the default
    assert abs(raw.forward.coefficients[2] - (0.334 - 0.05)) < 3 * raw.forward.stderr[2]
    # the fixture reads zero at rest, so taring moves the intercept back to the paper's
    assert abs(tared.forward.coefficients[2] - 0.334) < 3 * tared.forward.stderr[2]
    assert tared.forward.stderr[2] < 0.02


def test_drag_json_follows_the_contract(paper_fit):
    doc = json.loads(json.dumps(paper_fit.to_json(), allow_nan=False))
    for heading in ("forward", "lateral"):
        entry = doc[heading]
        assert len(entry["coefficients"]) == 3 and len(entry["stderr"]) == 3
        assert isinstance(entry["r2"], float)
        assert entry["speed_range_mps"][0] == pytest.approx(0.10, abs=0.002)
    assert doc["forward"]["flags"]


def test_parameters_from_the_repository_file_and_typos_refused():
    repo = Path(__file__).resolve().parents[2]  # the checkout (tests run with an isolated project root)
    params = DragFitSettings.from_dict(load_params(repo / "pipelines/drag.yaml", "fit"))
    assert params == DragFitSettings()
    with pytest.raises(ParamsError, match=r"fit\.plateau\.smoth_s.*did you mean .smooth_s"):
        DragFitSettings.from_dict({"plateau": {"smoth_s": 1.0}})
    with pytest.raises(ParamsError, match="weighting"):
        DragFitSettings.from_dict({"weighting": "magic"})


def test_missing_columns_refused():
    frame = towing_frame(speeds=(0.1, 0.2, 0.3)).drop("fy_n")
    with pytest.raises(ContractError, match="fy_n"):
        fit_drag(frame)


def test_standard_error_of_an_autocorrelated_mean_is_calibrated():
    # first-order (AR(1)) noise, correlation time 0.16 s at 100 Hz: the naive sigma/sqrt(N) is 6x too small
    from scipy import signal

    rng = np.random.default_rng(0)
    a = np.exp(-2 * np.pi * 0.01)
    series = [signal.lfilter([1 - a], [1, -a], rng.standard_normal(3800))[3000:] for _ in range(200)]
    spread = np.std([x.mean() for x in series])
    sem = np.sqrt(np.mean([mean_sem(x) ** 2 for x in series]))
    naive = np.mean([x.std(ddof=1) / np.sqrt(x.size) for x in series])
    assert 0.85 < sem / spread < 1.2
    assert naive < 0.3 * spread
