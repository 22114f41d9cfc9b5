"""The planted-effect battery of issue 13: plant rig effects into raw rich-truth campaigns, diagnose, score.

Used by ``tests/diagnose/test_diagnose_battery.py`` (slow) and by
``benchmarks/diagnose_battery.py``, which prints the confusion table (planted against named),
each effect's parameter error and the share of the planted held-out error removed.

Campaigns: the virtual lab's rich truth (physics the EF lacks: sin(alpha) normal force, Wagner
lag, KC-dependent added mass, links, weight), shrunk to a few parameter sets (the protocol is the
demo's: every set at every flow speed, a few cycles). The *reference* campaign (seed 1) and the
*new* campaign (seed 2) are two measurements of the same rig: same grid, other noise, biases,
drifts and clocks. Effects are planted into copies of the new campaign's raw CSV files by
``planting.py`` (formulas of its own), then the copy goes through ``workbench ingest``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import planting as P

SPEEDS = (0.0, 0.12, 0.25)
CYCLES = 4
#: parameter sets (theta_h_min, theta_k_max, f, phi) spread over the paper's ranges
GRID = [
    (10.0, -20.0, 0.3, np.pi / 3), (-10.0, -40.0, 0.4, 2 * np.pi / 3), (-30.0, -60.0, 0.5, np.pi),
    (-50.0, -80.0, 0.6, 4 * np.pi / 3), (10.0, -60.0, 0.6, 5 * np.pi / 3), (-30.0, -20.0, 0.3, 2 * np.pi / 3),
    (-10.0, -80.0, 0.5, np.pi / 3), (-50.0, -40.0, 0.4, np.pi), (10.0, -40.0, 0.5, 4 * np.pi / 3),
    (-30.0, -80.0, 0.4, 5 * np.pi / 3), (-50.0, -20.0, 0.5, 2 * np.pi / 3), (-10.0, -60.0, 0.3, np.pi),
]


def _more_sets() -> list[tuple]:
    """Sets beyond :data:`GRID` for larger campaigns (``--sets`` up to 64): the rest of the 4 x 4 x 4 grid of
    theta_h_min, theta_k_max and f in a fixed shuffled order, phases in turn (the first 12 stay GRID's)."""
    taken = {(a, b, f) for a, b, f, _ in GRID}
    rest = [(a, b, f) for a in (10.0, -10.0, -30.0, -50.0) for b in (-20.0, -40.0, -60.0, -80.0)
            for f in (0.3, 0.4, 0.5, 0.6) if (a, b, f) not in taken]
    order = np.random.default_rng(0).permutation(len(rest))
    return [(*rest[i], (1 + k % 5) * np.pi / 3) for k, i in enumerate(order)]


def grid(n_sets: int) -> list[dict]:
    """The first ``n_sets`` sets as manifest parameters (GRID's 12, then :func:`_more_sets`)."""
    sets = GRID + _more_sets()
    if not 1 <= n_sets <= len(sets):
        raise SystemExit(f"battery campaigns hold 1 to {len(sets)} parameter sets, not {n_sets}")
    return [dict(theta_h_min_deg=a, theta_h_max_deg=-100.0, theta_k_min_deg=80.0, theta_k_max_deg=b,
                 frequency_hz=f, phi_rad=p, alpha_rad=0.0) for a, b, f, p in sets[:n_sets]]


def rich_campaign(root: Path, seed: int, n_sets: int = 12) -> Path:
    """A rich-truth virtual tunnel campaign (CSV pairs), generated once per folder."""
    from workbench.virtual_lab.tunnel import generate_tunnel

    name = f"rich-s{seed}-n{n_sets}"
    out = root / name
    if not (out / "campaign.toml").is_file():
        generate_tunnel(out, seed=seed, truth="rich", grid=grid(n_sets), cycles=CYCLES, flow_speeds=SPEEDS,
                        campaign_id=name)
    return out


@dataclass
class Case:
    """A planting: what is planted, and what a right diagnosis names."""

    name: str
    plants: Callable[[], list]
    #: effect -> planted canonical parameters (compared within 20 %); an empty dict: named, parameters
    #: not comparable (another parametrisation of the same physics)
    expected: dict[str, dict[str, float]] = field(default_factory=dict)
    #: effects of the library that also name this physics (a static load by a spread weight)
    family: dict[str, tuple[str, ...]] = field(default_factory=dict)
    #: out-of-library disturbances: (frequency_hz, channels) that must come back as unexplained lines
    lines: list[tuple[float, tuple[str, ...]]] = field(default_factory=list)
    #: every plant acts on the readings (a crosstalk, a drift, a mount mode): a lab corrects its readings
    #: with them, so "removed" is scored against the corrected readings (``Diagnosis.mse_after_corrected``)
    sensor_side: bool = False


#: the library's parametrisations of static weight and buoyancy loads (one physics when the truth has them)
STATIC_LOADS = ("leg_weight_buoyancy", "link_weight_buoyancy", "weight_buoyancy_couple")


SINGLES = [
    Case("servo_dead_60ms", lambda: [P.servo_dead_time(0.06)], {"servo_lag": {"tau_s": 0.06}}),
    Case("servo_dead_25ms", lambda: [P.servo_dead_time(0.025)], {"servo_lag": {"tau_s": 0.025}}),
    Case("crosstalk_fz_from_fy_3pc", lambda: [P.crosstalk("fz_n", "fy_n", 0.03)],
         {"loadcell_crosstalk": {"x_fz_fy": 0.03}}, sensor_side=True),
    Case("crosstalk_tx_from_fz_2pc", lambda: [P.crosstalk("tx_nm", "fz_n", 0.02)],
         {"loadcell_crosstalk": {"x_tx_fz": 0.02}}, sensor_side=True),
    Case("drift_fz_1.5mN_per_s", lambda: [P.drift("fz_n", 0.0015)], {"sensor_drift": {"rate_fz_n_per_s": 0.0015}},
         sensor_side=True),
    Case("mount_mode_4.5Hz", lambda: [P.mode(4.5, 0.08)], {"structural_resonance": {"f_n_hz": 4.5, "zeta": 0.08}},
         sensor_side=True),
    Case("static_hip_torque", lambda: [P.hip_weight(0.003)], {"leg_weight_buoyancy": {}},
         family={"leg_weight_buoyancy": STATIC_LOADS}),
    Case("flow_tone_2Hz_5pc", lambda: [P.flow_tone(2.0, 0.05)],
         {"flow_unsteadiness": {"tone_hz": 2.0, "tone_fraction": 0.05}}),
    Case("vibration_3.3Hz", lambda: [P.vibration(3.3, {"fy_n": 0.01, "fz_n": 0.01})],
         lines=[(3.3, ("fy_n", "fz_n"))]),
]

#: servos planted by re-timing the command log: the leg's actual motion (and so the force) is the
#: reference campaign's, the command leads it. Valid without a reference (the model sees the command).
COMMAND_SERVOS = [
    Case("servo_cmd_10ms_dead_40ms_lag", lambda: [P.servo(dead_s=0.01, lag_s=0.04)], {"servo_lag": {"tau_s": 0.05}}),
    Case("servo_cmd_lag_25ms", lambda: [P.servo(lag_s=0.025)], {"servo_lag": {"tau_s": 0.025}}),
]

#: the ends of issue 13's tone range (1-4 Hz at 3-10 % of the flow speed). Not in the slow CI test
#: with a reference (its time); ``all_cases(with_reference=False)`` and ``case`` find them
TONE_RANGE = [
    Case("flow_tone_1Hz_3pc", lambda: [P.flow_tone(1.0, 0.03, seed=1)],
         {"flow_unsteadiness": {"tone_hz": 1.0, "tone_fraction": 0.03}}),
    Case("flow_tone_4Hz_10pc", lambda: [P.flow_tone(4.0, 0.10, seed=2)],
         {"flow_unsteadiness": {"tone_hz": 4.0, "tone_fraction": 0.10}}),
]

def _calf_weight(k_nm: float):
    """A heavy part on the calf: a static torque ``k cos(theta_h + theta_k / 2)`` about the hip (the probe's own)."""

    def plant(lc, mo, run):
        th = np.interp(lc["t_ctrl"], mo["time_s"], mo["hfe_cmd_deg"])
        tk = np.interp(lc["t_ctrl"], mo["time_s"], mo["kfe_cmd_deg"])
        lc["tx_nm"] = lc["tx_nm"] + k_nm * np.cos(np.radians(th + 0.5 * tk))

    return plant


#: a generalisation probe: what the battery does not plant (other channel pairs, a delay between its two,
#: another mode, tone and vibration frequency, a torque drift, a static load of another shape). Not in the
#: CI tests; ``benchmarks/diagnose_battery.py --cases probe`` runs them (docs/diagnose.md section 7)
PROBE = [
    Case("xt_fx_from_fz_4pc", lambda: [P.crosstalk("fx_n", "fz_n", 0.04)], {"loadcell_crosstalk": {"x_fx_fz": 0.04}},
         sensor_side=True),
    Case("xt_ty_from_fy_3pc", lambda: [P.crosstalk("ty_nm", "fy_n", 0.03)], {"loadcell_crosstalk": {"x_ty_fy": 0.03}},
         sensor_side=True),
    Case("servo_dead_40ms", lambda: [P.servo_dead_time(0.04)], {"servo_lag": {"tau_s": 0.04}}),
    Case("drift_tx", lambda: [P.drift("tx_nm", 0.0003)], {"sensor_drift": {"rate_tx_nm_per_s": 0.0003}},
         sensor_side=True),
    Case("mode_2.5Hz", lambda: [P.mode(2.5, 0.06)], {"structural_resonance": {"f_n_hz": 2.5, "zeta": 0.06}},
         sensor_side=True),
    Case("tone_3Hz_8pc", lambda: [P.flow_tone(3.0, 0.08, seed=5)],
         {"flow_unsteadiness": {"tone_hz": 3.0, "tone_fraction": 0.08}}),
    Case("vib_6Hz_fx_tx", lambda: [P.vibration(6.0, {"fx_n": 0.012, "tx_nm": 0.0015}, seed=3)],
         lines=[(6.0, ("fx_n", "tx_nm"))]),
    Case("calf_weight", lambda: [_calf_weight(0.004)], {"leg_weight_buoyancy": {}},
         family={"leg_weight_buoyancy": STATIC_LOADS}),
]

#: a second probe (30 Nov 2026): the ends of issue 13's ranges the others do not reach, on channel
#: pairs they do not use (1 % crosstalk, 20 and 80 ms, a drift in fy, a 1.5 Hz / 10 % tone, vibration at
#: 2.2 Hz and 8 Hz, a mount mode above the low-pass cutoff)
PROBE2 = [
    Case("xt_fy_from_fz_1pc", lambda: [P.crosstalk("fy_n", "fz_n", 0.01)], {"loadcell_crosstalk": {"x_fy_fz": 0.01}},
         sensor_side=True),
    Case("servo_dead_20ms", lambda: [P.servo_dead_time(0.02)], {"servo_lag": {"tau_s": 0.02}}),
    Case("servo_dead_80ms", lambda: [P.servo_dead_time(0.08)], {"servo_lag": {"tau_s": 0.08}}),
    Case("drift_fy", lambda: [P.drift("fy_n", 0.001)], {"sensor_drift": {"rate_fy_n_per_s": 0.001}},
         sensor_side=True),
    Case("tone_1.5Hz_10pc", lambda: [P.flow_tone(1.5, 0.10, seed=7)],
         {"flow_unsteadiness": {"tone_hz": 1.5, "tone_fraction": 0.10}}),
    Case("vib_2.2Hz_fz", lambda: [P.vibration(2.2, {"fz_n": 0.01}, seed=4)], lines=[(2.2, ("fz_n",))]),
    Case("vib_8Hz_fy", lambda: [P.vibration(8.0, {"fy_n": 0.02}, seed=6)], lines=[(8.0, ("fy_n",))]),
    Case("mode_7Hz", lambda: [P.mode(7.0, 0.05)], {"structural_resonance": {"f_n_hz": 7.0, "zeta": 0.05}},
         sensor_side=True),
]

#: members of the third probe's pairs that no other list plants (a force-to-torque crosstalk on tz, a
#: vibration in tz alone, a fast weak tone)
PROBE3_SINGLES = [
    Case("xt_tz_from_fx_3pc", lambda: [P.crosstalk("tz_nm", "fx_n", 0.03)], {"loadcell_crosstalk": {"x_tz_fx": 0.03}},
         sensor_side=True),
    Case("vib_5Hz_tz", lambda: [P.vibration(5.0, {"tz_nm": 0.002}, seed=8)], lines=[(5.0, ("tz_nm",))]),
    Case("tone_4Hz_3pc", lambda: [P.flow_tone(4.0, 0.03, seed=9)],
         {"flow_unsteadiness": {"tone_hz": 4.0, "tone_fraction": 0.03}}),
]

#: a third probe (30 Nov 2026): pairs the battery does not plant, chosen where effects trade off (a
#: servo beside a low-pass mount mode, a drift beside a static torque on the same channel, a tone beside
#: a crosstalk) or where one hides the other (a line beside a crosstalk on the same channel)
PROBE3_PAIRS = [
    ("servo_dead_40ms", "mount_mode_4.5Hz"),
    ("flow_tone_2Hz_5pc", "crosstalk_tx_from_fz_2pc"),
    ("drift_tx", "static_hip_torque"),
    ("servo_cmd_lag_25ms", "tone_3Hz_8pc"),
    ("xt_tz_from_fx_3pc", "vib_5Hz_tz"),
    ("servo_dead_80ms", "drift_fy"),
    ("mode_7Hz", "servo_dead_20ms"),
]

#: a fourth probe (30 Nov 2026): pairs of the rig effects the issue's own check planted (servos, crosstalks,
#: static loads, tones, vibration, drift; no mount mode), none of them in the battery's pairs
PROBE4_PAIRS = [
    ("servo_dead_25ms", "crosstalk_fz_from_fy_3pc"),
    ("flow_tone_4Hz_10pc", "vibration_3.3Hz"),
    ("crosstalk_tx_from_fz_2pc", "drift_fz_1.5mN_per_s"),
    ("servo_cmd_10ms_dead_40ms_lag", "static_hip_torque"),
    ("xt_fx_from_fz_4pc", "xt_ty_from_fy_3pc"),
    ("vib_8Hz_fy", "servo_dead_60ms"),
    ("flow_tone_1Hz_3pc", "drift_tx"),
]

PAIRS = [
    ("servo_dead_60ms", "drift_fz_1.5mN_per_s"),
    ("crosstalk_fz_from_fy_3pc", "mount_mode_4.5Hz"),
    ("static_hip_torque", "vibration_3.3Hz"),
]


def case(name: str) -> Case:
    """A single case by name."""
    return next(c for c in SINGLES + COMMAND_SERVOS + TONE_RANGE + PROBE + PROBE2 + PROBE3_SINGLES
                if c.name == name)


def pair(a: str, b: str) -> Case:
    """Two cases planted together."""
    ca, cb = case(a), case(b)
    return Case(f"{a}+{b}", lambda: ca.plants() + cb.plants(), {**ca.expected, **cb.expected},
                {**ca.family, **cb.family}, ca.lines + cb.lines, ca.sensor_side and cb.sensor_side)


def probe3() -> list[Case]:
    """The third probe: its pairs, then its one single (the 4 Hz / 3 % tone)."""
    return [pair(a, b) for a, b in PROBE3_PAIRS] + [case("tone_4Hz_3pc")]


def probe4() -> list[Case]:
    """The fourth probe's pairs (two crosstalk entries are planted as one case expecting both)."""
    out = []
    for a, b in PROBE4_PAIRS:
        c = pair(a, b)
        if a.startswith("xt_") and b.startswith("xt_"):  # both entries belong to the one crosstalk effect
            merged = {**case(a).expected["loadcell_crosstalk"], **case(b).expected["loadcell_crosstalk"]}
            c.expected = {"loadcell_crosstalk": merged}
        out.append(c)
    return out


def all_cases(with_reference: bool = True) -> list[Case]:
    """Singles, then pairs (command-log servos only without a reference)."""
    return SINGLES + ([] if with_reference else COMMAND_SERVOS + TONE_RANGE) + [pair(a, b) for a, b in PAIRS]


# ------------------------------------------------------------------------------ running
class Bench:
    """Campaigns, their ingested frames and clean diagnoses, made once per folder and model."""

    def __init__(self, root: Path, n_sets: int = 12, max_runs: int = 0, data: dict | None = None):
        self.root = Path(root)
        self.n_sets = n_sets
        self.max_runs = max_runs
        #: further ``DataSettings`` values for every diagnosis (a benchmark's ``--data``)
        self.data = dict(data or {})
        self._frames: dict[str, object] = {}
        self._clean: dict[tuple, object] = {}

    def frame(self, folder: Path):
        from workbench.ingest import ingest_campaign

        key = str(folder)
        if key not in self._frames:
            self._frames[key] = ingest_campaign(folder, params={"workers": 1}).frame
        return self._frames[key]

    def problem(self, folder: Path, model_spec: str = "ef", drop_rest: bool = False):
        """The fitting problem of a campaign folder against a base model (optionally without its rest stretches)."""
        import polars as pl

        from workbench.diagnose.chain import Lowpass
        from workbench.diagnose.data import prepare
        from workbench.diagnose.problem import Problem

        frame = self.frame(folder)
        if drop_rest:
            frame = frame.filter(pl.col("time_s") >= 0)
        return Problem(prepare(frame), _model(model_spec), Lowpass(6.0, 4))

    def reference(self):
        return self.frame(rich_campaign(self.root, 1, self.n_sets))

    def new_campaign(self) -> Path:
        return rich_campaign(self.root, 2, self.n_sets)

    def diagnose(self, frame, model_spec: str, with_reference: bool):
        import dataclasses

        from workbench.diagnose.loop import DiagnoseSettings, diagnose

        s = DiagnoseSettings()
        s = dataclasses.replace(s, data=dataclasses.replace(s.data, max_runs=self.max_runs, **self.data))
        model = _model(model_spec)
        return diagnose(frame, model, model_spec, settings=s,
                        reference=self.reference() if with_reference else None)

    def clean(self, model_spec: str, with_reference: bool):
        key = (model_spec, with_reference)
        if key not in self._clean:
            self._clean[key] = self.diagnose(self.frame(self.new_campaign()), model_spec, with_reference)
        return self._clean[key]

    def run(self, c: Case, model_spec: str, with_reference: bool) -> dict:
        t0 = time.perf_counter()
        dst = P.copy_campaign(self.new_campaign(), self.root / f"p-{_slug(c.name)}", c.plants())
        d = self.diagnose(self.frame(dst), model_spec, with_reference)
        out = score(c, d, self.clean(model_spec, with_reference))
        out["seconds"] = time.perf_counter() - t0
        return out


_MODELS: dict[str, object] = {}


def _model(spec: str):
    from workbench.hydro.legmodel import load_leg_model

    if spec not in _MODELS:
        _MODELS[spec] = load_leg_model(spec)
    return _MODELS[spec]


def _slug(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "-" for ch in name.lower())[:60]


def score(c: Case, d, clean) -> dict:
    """What a diagnosis named against what was planted, parameter errors and the error removed."""
    from workbench.contract.columns import WRENCH_CHANNELS

    named = {e.name: e for e in d.effects}
    clean_names = {e.name for e in clean.effects}
    if clean_names & set(STATIC_LOADS):
        # the rich truth's weight and buoyancy, spread over the links: its parametrisations are one physics
        clean_names |= set(STATIC_LOADS)
    hits, param_err = {}, {}
    for eff, params in c.expected.items():
        names = c.family.get(eff, (eff,))
        got = next((named[n] for n in names if n in named), None)
        hits[eff] = got.name if got else None
        if got is not None and got.name == eff:
            for k, v in params.items():
                g = got.params.get(k)
                param_err[f"{eff}.{k}"] = (abs(g - v) / abs(v)) if isinstance(g, (int, float)) else None
    family = {n for eff in c.expected for n in c.family.get(eff, (eff,))}
    extra = sorted(set(named) - family - clean_names)
    lines_ok = []
    for f, chans in c.lines:
        ok = any(u.kind == "narrowband" and u.frequency_hz is not None and abs(u.frequency_hz - f) < 0.1
                 and set(chans) <= set(u.channels) for u in d.unexplained)
        lines_ok.append(ok)
    ch = list(WRENCH_CHANNELS)
    b = np.array([d.mse_before[k] for k in ch])
    a = np.array([d.mse_after[k] for k in ch])
    cb = np.array([clean.mse_before[k] for k in ch])
    ca = np.array([clean.mse_after[k] for k in ch])
    added = b - cb
    hit = added > 0.05 * cb
    share = _share(b, a, cb, ca, hit)
    # against the readings corrected by the claimed sensor-side effects (the clean diagnosis' own, if any)
    corr, clean_corr = d.mse_after_corrected(), clean.mse_after_corrected()
    share_corr = None if corr is None else _share(b, np.array([corr[k] for k in ch]), cb, ca if clean_corr is None
                                                  else np.array([clean_corr[k] for k in ch]), hit)
    return {"case": c.name, "named": sorted(named), "hits": hits, "param_err": param_err, "extra": extra,
            "lines_ok": lines_ok, "removed_share_output": share, "removed_share_corrected": share_corr,
            "removed_share": share_corr if c.sensor_side and share_corr is not None else share, "channels": [k for k, h in zip(ch, hit, strict=True) if h],
            "unexplained": [(u.kind, u.channels, None if u.frequency_hz is None else round(u.frequency_hz, 2))
                            for u in d.unexplained],
            "ambiguous": {e.name: e.ambiguous_with for e in d.effects if e.ambiguous_with},
            # acceptable candidates left when the selection's round budget ran out (empty: it converged)
            "left_at_budget": [r["effect"] for r in d.left_at_budget],
            # fits whose fixed point was not reached (empty: all settled)
            "unsettled": list(d.unsettled),
            "params": {e.name: {k: (round(v, 5) if isinstance(v, float) else v) for k, v in e.params.items()}
                       for e in d.effects}}


def _budget_note(r: dict) -> str:
    """' (not converged: X, Y left)' when the case's selection ran out of rounds with acceptable candidates left."""
    left = r.get("left_at_budget") or []
    note = f" (not converged: {', '.join(left)} left)" if left else ""
    return note + (" (fit not settled)" if r.get("unsettled") else "")


def _share(b, a, cb, ca, hit) -> float | None:
    """Share of the planted held-out error removed, in the channels the plant raised (each scaled by the clean error)."""
    if not hit.any():
        return None
    removed = (b - a) - (cb - ca)
    added = b - cb
    return float((removed[hit] / cb[hit]).sum() / (added[hit] / cb[hit]).sum())


def table(results: list[dict], title: str) -> str:
    """Confusion table (planted against named) and per-case numbers, as Markdown."""
    lines = [f"### {title}", "", "| planted | named | parameter error | planted error removed | "
             "lines | extra claims | s |", "|---|---|---|---|---|---|---|"]
    for r in results:
        hits = ", ".join(f"{k}->{v or 'MISSED'}" for k, v in r["hits"].items()) or "-"
        pe = ", ".join(f"{k.split('.', 1)[1]} {v:.0%}" if v is not None else f"{k} ?" for k, v in r["param_err"].items())
        sh = "-" if r["removed_share"] is None else f"{r['removed_share']:.0%}"
        if r.get("removed_share_corrected") is not None and r.get("removed_share_output") is not None:
            sh += f" (output {r['removed_share_output']:.0%}, corrected {r['removed_share_corrected']:.0%})"
        lines.append(f"| {r['case']} | {hits} | {pe or '-'} | {sh} | {r['lines_ok'] or '-'} | "
                     f"{', '.join(r['extra']) or '-'}{_budget_note(r)} | {r['seconds']:.0f} |")
    planted = [v for r in results for v in r["hits"].values()]
    named = sum(v is not None for v in planted)
    perr = [v for r in results for v in r["param_err"].values()]
    within = sum(v is not None and v <= 0.2 for v in perr)
    shares = [r["removed_share"] for r in results if r["removed_share"] is not None and r["hits"]]
    lines += ["", f"named {named}/{len(planted)} planted in-library effects; parameters within 20 %: "
              f"{within}/{len(perr)}; planted held-out error removed (median over cases): "
              f"{np.median(shares):.0%}" if shares else "", ""]
    return "\n".join(lines)


def clean_and_planted_with_one_effect(root: Path, model_folder: Path, effect: str, plant, n_sets: int) -> dict:
    """The clean rich-truth campaign and a copy with ``plant``, each diagnosed against the learned model in
    ``model_folder`` with ``effect`` the only candidate (the learned-base tests' shared setup)."""
    import dataclasses

    from workbench.diagnose.loop import DiagnoseSettings, LibrarySettings, diagnose
    from workbench.hydro.legmodel import load_leg_model

    bench = Bench(root, n_sets=n_sets)
    model = load_leg_model(str(model_folder))
    s = dataclasses.replace(DiagnoseSettings(), library=LibrarySettings(effects=(effect,)))
    clean = bench.new_campaign()
    planted = P.copy_campaign(clean, bench.root / "planted", [plant])
    return {name: diagnose(bench.frame(folder), model, "lstm", settings=s)
            for name, folder in (("clean", clean), ("planted", planted))}
