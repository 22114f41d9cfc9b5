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
    from workbench.diagnose.effects.flow_tone import FlowUnsteadiness
    from workbench.errors import ModelError

    e = FlowUnsteadiness.from_options({"sensitivity": "model", "stroke_free": False})
    assert e.options() == {"sensitivity": "model", "stroke_free": False}
    assert FlowUnsteadiness().options() == {"sensitivity": "measured", "stroke_free": "auto"}
    with pytest.raises(ModelError, match="sensitivity"):
        FlowUnsteadiness(sensitivity="guess")
    with pytest.raises(ModelError, match="stroke_free"):
        FlowUnsteadiness(stroke_free="sometimes")


def _tone_context(freqs: list[float], t: np.ndarray, u: float = 0.2, offset=None):
    """A batch as the tone's columns see it: runs at ``freqs`` (Hz gait), their flow sensitivity ``_force``.

    The model's flow sensitivity (a centred difference of the wrench at scaled flow speeds) is the
    readings' quadratic here: the model is the test's own formula.
    """
    b = len(freqs)
    mask = np.ones((b, len(t)), bool)
    mask[:, :30] = mask[:, -30:] = False
    rs = SimpleNamespace(run_ids=None, flow=np.full(b, u), fit=mask, freq=np.array(freqs), offset=offset,
                         time_s=np.tile(t, (b, 1)))
    return SimpleNamespace(rs=rs, time_s=rs.time_s, dt_s=DT,
                           wrench_at_flow=lambda k: np.stack([_force(u * k, t, f) for f in freqs]))


def test_runs_on_a_gait_harmonic_carry_the_tone_apart_and_the_nulls_keep_it():
    from workbench.diagnose.effects.flow_tone import FlowUnsteadiness
    from workbench.diagnose.flowsens import without_stroke

    t = np.arange(0, 4 / 0.3, DT)
    ctx = _tone_context([0.3, 0.5, 0.6], t)              # 2 Hz: the 4th harmonic of 0.5 Hz only
    e = FlowUnsteadiness(sensitivity="model", stroke_free="auto")
    terms = e.force_terms(ctx, {"tone_hz": 2.0})
    s1, c1, s2, c2 = terms.local
    assert terms.local_names == ["tone_sin", "tone_cos", "tone_sin_h", "tone_cos_h"]
    g = e.gain(ctx)
    raw = g * np.sin(2 * np.pi * 2.0 * t)[None, :, None]
    # the run on the harmonic: only the second pair, the tone's own column
    assert np.all(s1[1] == 0) and np.allclose(s2[1], raw[1])
    # the others: only the first pair, stroke-free (nothing left at the gait harmonics)
    for i in (0, 2):
        assert np.all(s2[i] == 0) and np.all(c2[i] == 0)
        again = without_stroke(s1[i:i + 1], ctx.time_s[i:i + 1], ctx.rs.fit[i:i + 1], ctx.rs.freq[i:i + 1])
        assert np.allclose(again, s1[i:i + 1], atol=1e-9 * np.abs(s1[i]).max())
        assert np.sum(s1[i][ctx.rs.fit[i]] ** 2) > 0.5 * np.sum(raw[i][ctx.rs.fit[i]] ** 2)
    # an off-peak null fit: the harmonic run keeps the candidate's columns (no evidence either way there)
    null = e.force_terms(ctx, e.null_variants({"tone_hz": 2.0})[0])
    assert np.allclose(null.local[2][1], s2[1]) and not np.allclose(null.local[0][0], s1[0])
    # with a reference (an offset): the plain columns everywhere; outside a diagnosis: both pairs plain
    ref = e.force_terms(_tone_context([0.3, 0.5, 0.6], t, offset=np.zeros(1)), {"tone_hz": 2.0})
    assert np.allclose(ref.local[0], raw) and np.all(ref.local[2] == 0)
    bare = SimpleNamespace(rs=SimpleNamespace(run_ids=None, flow=ctx.rs.flow), time_s=ctx.time_s, dt_s=DT,
                           wrench_at_flow=ctx.wrench_at_flow)
    out = e.force_terms(bare, {"tone_hz": 2.0})
    assert np.allclose(out.local[0], raw) and np.allclose(out.local[2], raw)


def _amplitude(cols, i, m, y):
    """One run's tone amplitude by least squares on its columns (one coefficient pair over the six channels)."""
    x = np.stack([c[i][m].ravel() for c in cols], axis=1)
    return float(np.hypot(*np.linalg.lstsq(x, y[m].ravel(), rcond=None)[0]))


def test_stroke_free_columns_measure_the_tone_under_a_large_stroke_locked_misfit():
    """Per run, least squares on the stroke-free columns gives the planted amplitude; the plain ones do not."""
    from workbench.diagnose.effects.flow_tone import FlowUnsteadiness

    t = np.arange(0, 4 / 0.3, DT)
    freqs = [0.3, 0.45, 0.6]
    ctx = _tone_context(freqs, t)
    e = FlowUnsteadiness(sensitivity="model", stroke_free=True)
    g = e.gain(ctx)
    rng = np.random.default_rng(7)
    amp = 0.05
    for tone_hz in (1.05, 2.55):               # off every run's gait harmonics
        terms = e.force_terms(ctx, {"tone_hz": tone_hz})
        plain = FlowUnsteadiness(sensitivity="model", stroke_free=False).force_terms(
            SimpleNamespace(**{**vars(ctx), "rs": SimpleNamespace(**{**vars(ctx.rs), "offset": np.zeros(1)})}),
            {"tone_hz": tone_hz})
        for i, f in enumerate(freqs):
            m = ctx.rs.fit[i]
            ph = rng.uniform(0, 2 * np.pi)
            w = 2 * np.pi * f * t
            # a misfit 30x the tone, periodic in the stroke, with harmonics up to 6 Hz
            misfit = 30 * amp * np.abs(g[i]).max() * np.stack(
                [sum(np.sin(k * w + rng.uniform(0, 6)) / k for k in range(1, int(6 / f) + 1)) for _ in range(6)], -1)
            y = misfit + amp * g[i] * np.sin(2 * np.pi * tone_hz * t + ph)[:, None] \
                + 1e-4 * rng.standard_normal((len(t), 6))

            assert abs(_amplitude(terms.local[:2], i, m, y) - amp) < 0.05 * amp, (tone_hz, f)
            if f == 0.3:
                assert abs(_amplitude(plain.local[:2], i, m, y) - amp) > 0.2 * amp, tone_hz


def _per_run_fits(amps: list[float], scales: list[float], tone_hz: float, nulls_hz: list[float], seed: int,
                  cost: list[float] | None = None, with_sse: bool = False):
    """Held-out runs of coloured noise plus a tone of amplitude ``amps[r]``, fitted per run at the tone and off it.

    The test's own least squares: per run, ``sin``/``cos`` at one frequency, fitted over the whole
    run (a per-run nuisance), SSE per 2 s block before and after. Returns ``(before, after, grams,
    nulls)`` shaped as ``selection.judge`` reads them.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0, 12, 0.02)
    blocks = (t // 2).astype(int)
    nb = blocks.max() + 1
    sse_b, sse_a, sse_n, run, energy = [], [], [], [], 0.0
    cost = cost or [0.0] * len(amps)
    for r, (amp, sc) in enumerate(zip(amps, scales, strict=True)):
        noise = np.convolve(rng.standard_normal(len(t) + 9), np.ones(10) / 10, mode="valid") * sc
        tone = amp * np.sin(2 * np.pi * tone_hz * t + rng.uniform(0, 6))
        e = noise + tone
        energy += float(tone @ tone)

        def left(f, e=e):
            x = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)])
            return e - x @ np.linalg.lstsq(x, e, rcond=None)[0]

        blk = lambda v: np.bincount(blocks, v ** 2, minlength=nb)[:, None] * np.ones(6)  # noqa: E731
        extra = cost[r] * blk(e)
        sse_b.append(blk(e))
        sse_a.append(blk(left(tone_hz)) + extra)
        sse_n.append([blk(left(f)) + extra for f in nulls_hz])
        run += [r] * nb
    before = SimpleNamespace(sse_block_c=np.concatenate(sse_b))
    after = SimpleNamespace(sse_block_c=np.concatenate(sse_a))
    n = np.full(len(run), len(t) // nb)
    gr = SimpleNamespace(n=n, heldout=np.ones(len(run), bool), run=np.array(run), order=np.tile(np.arange(nb), len(amps)))
    nulls = np.array([(0.5 * n[:, None] * np.log(before.sse_block_c / np.concatenate([s[k] for s in sse_n]))).sum(axis=1)
                      for k in range(len(nulls_hz))])
    if with_sse:
        null_sse = np.array([np.concatenate([s[k] for s in sse_n]) for k in range(len(nulls_hz))])
        return before, after, gr, nulls, null_sse, energy
    return before, after, gr, nulls


def test_a_per_run_tone_is_judged_against_the_spread_of_its_off_peak_fits():
    """A tone in two runs, 16x stronger in one (twice the flow speed), is evidence; without a tone nothing passes."""
    from workbench.diagnose.selection import judge

    nulls_hz = [1.4, 1.55, 1.7, 2.3, 2.45, 2.6]
    # the tone rides on U dF/dU: a quarter of the amplitude at half the flow speed; two runs carry none (a
    # gait harmonic hides it there)
    before, after, gr, nulls = _per_run_fits([0.3, 0.075, 0.0, 0.0], [1.0] * 4, 2.0, nulls_hz, seed=4)
    spread, _ = judge(before, after, gr, 2, nulls)
    blocks, _ = judge(before, after, gr, 2, nulls.mean(axis=0))    # the blocks' own scatter (fewer variants)
    assert spread["p"] < 1e-3, spread
    assert spread["p"] < 0.1 * blocks["p"], (spread, blocks)
    # no tone: the fit at 2 Hz is one more draw of the off-peak fits (coloured noise, runs of unequal level)
    ps = []
    for seed in range(40):
        b, a, g, n = _per_run_fits([0.0] * 4, [1.0, 4.0, 0.5, 2.0], 2.0, nulls_hz, seed=seed)
        ps.append(judge(b, a, g, 2, n)[0]["p"])
    # (a t on the runs' summed gains, normal in the variants' spread, gave 4.5e-5 here: a gain is a chi-square)
    assert min(ps) > 1e-3 and sum(p < 0.01 for p in ps) <= 2, sorted(ps)[:5]


def test_a_per_run_tone_s_gain_is_what_it_removes_beyond_its_off_peak_fits():
    """Moving the shared coefficients costs every per-run fit alike: the tone's gain is counted beyond the variants.

    Two held-out runs carry a tone; in the two others any per-run fit (at the tone or off it) costs 30 % of
    their error. Measured plainly the tone fit removes nothing; beside its variants it removes the tone.
    """
    from workbench.diagnose.selection import judge

    nulls_hz = [1.4, 1.55, 1.7, 2.3, 2.45, 2.6]
    before, after, gr, nulls, null_sse, energy = _per_run_fits(
        [0.3, 0.15, 0.0, 0.0], [1.0] * 4, 2.0, nulls_hz, seed=7, cost=[0.0, 0.0, 0.3, 0.3], with_sse=True)
    test, gain = judge(before, after, gr, 2, nulls, null_sse)
    _, plain = judge(before, after, gr, 2)
    share = energy / before.sse_block_c[:, 0].sum()          # the tone's own share of the error (the test's sums)
    assert test["p"] < 1e-3, test
    assert plain.max() < 0.02 < share, (plain, share)
    assert abs(gain.max() - share) < 0.25 * share, (gain, share)
    # counted over the runs that can tell the tone (here the first two), the share is of their error alone
    telling = np.isin(gr.run, [0, 1])
    _, told = judge(before, after, gr, 2, nulls, null_sse, telling)
    share_told = energy / before.sse_block_c[telling, 0].sum()
    assert share_told > 1.5 * share and abs(told.max() - share_told) < 0.25 * share_told, (told, share_told)
    # no tone: beyond its variants the fit at 2 Hz removes about nothing
    gains = []
    for seed in range(20):
        b, a, g, n, ns, _ = _per_run_fits([0.0] * 4, [1.0] * 4, 2.0, nulls_hz, seed=seed, cost=[0.0, 0.0, 0.3, 0.3],
                                          with_sse=True)
        gains.append(judge(b, a, g, 2, n, ns)[1].max())
    assert max(gains) < 0.02, sorted(gains)[-3:]
