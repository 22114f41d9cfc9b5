"""Processed-format tunnel frames with planted effects, for the diagnosis tests.

The truth is computed at 8x the control tick rate: commanded sinusoid (paper eq. 3) -> servo
lag (continuous first-order system) -> the virtual lab's ``TrueLegModel`` (EF truth plus its
planted force terms) on the unsteady, blocked flow -> structural mode (continuous 2nd-order
system) -> crosstalk, drift, pickup -> load-cell noise -> the ingest's 6 Hz zero-phase low-pass
-> the control ticks. Everything here is written independently of workbench.diagnose.
"""

from __future__ import annotations

import numpy as np
import polars as pl
from scipy import signal

from workbench.contract.columns import WRENCH_CHANNELS
from workbench.hydro.motion import JointSinusoid, LegMotion
from workbench.signals.filters import lowpass
from workbench.virtual_lab.physics import TrueLegModel

SHORT = ("fx", "fy", "fz", "tx", "ty", "tz")

GRID = [  # theta_h_min, theta_k_max, f, phi  (paper table ranges)
    (10.0, -20.0, 0.3, np.pi / 3), (-10.0, -40.0, 0.4, 2 * np.pi / 3), (-30.0, -60.0, 0.5, np.pi),
    (-50.0, -80.0, 0.6, 4 * np.pi / 3), (10.0, -60.0, 0.6, 5 * np.pi / 3), (-30.0, -20.0, 0.3, 2 * np.pi / 3),
    (-10.0, -80.0, 0.5, np.pi / 3), (-50.0, -40.0, 0.4, np.pi), (10.0, -40.0, 0.5, 4 * np.pi / 3),
    (-30.0, -80.0, 0.4, 5 * np.pi / 3), (-50.0, -20.0, 0.5, 2 * np.pi / 3), (-10.0, -60.0, 0.3, np.pi),
]


def parse(spec: str) -> tuple[str, dict]:
    """'servo_lag:tau_s=0.04' -> ('servo_lag', {'tau_s': 0.04}); channels as a|b lists."""
    name, _, rest = spec.partition(":")
    out: dict = {}
    for part in filter(None, rest.split(",")):
        k, _, v = part.partition("=")
        out[k] = v.split("|") if k == "channels" else float(v)
    return name, out


def make_frame(effects=(), *, n_sets: int = 8, speeds=(0.0, 0.12, 0.25), cycles: float = 4.0, seed: int = 0,
               rest_s: float = 1.5, noise=(0.002, 0.002, 0.002, 1e-4, 5e-5, 5e-5), up: int = 8,
               rate_hz: float = 65.0) -> pl.DataFrame:
    """A processed frame (contract section 3) of ``n_sets`` parameter sets x ``speeds``."""
    rng = np.random.default_rng(seed)
    fx = dict(parse(s) for s in effects)
    truth_kw = {}
    if "added_mass_error" in fx:
        truth_kw["extra_added_mass_kg"] = fx["added_mass_error"]["delta_kg"]
    if "drag_coefficient_error" in fx:
        truth_kw["extra_normal_drag_c"] = fx["drag_coefficient_error"]["delta_c"]
    if "link_drag" in fx:
        truth_kw["extra_link_cd_d_m"] = fx["link_drag"]["cd_d_m"]
    if "lift" in fx:
        truth_kw["lift_cl"] = fx["lift"]["cl"]
    if "circulatory_lag" in fx:
        truth_kw["series_lag_tau_chords"] = fx["circulatory_lag"]["tau_chords"]
    if "leg_weight_buoyancy" in fx:
        p = fx["leg_weight_buoyancy"]
        truth_kw["point_loads"] = ((p["net_n"], p["arm_m"]),)
    truth = TrueLegModel("ef").with_params(**truth_kw)
    dt = 1.0 / rate_hz
    dtf = dt / up
    frames = []
    run = 0
    for (thmin, tkmax, f, phi) in GRID[:n_sets]:
        js = JointSinusoid(thmin, -100.0, 80.0, tkmax, f, phi, 0.0)
        dur = cycles / f
        for u in speeds:
            run += 1
            n_f = int(round((rest_s + dur) / dtf)) + 1
            tf = -rest_s + dtf * np.arange(n_f)
            th, tk, wh, wk, _, _ = js.evaluate(np.maximum(tf, 0.0))
            wh, wk = np.where(tf >= 0, wh, 0.0), np.where(tf >= 0, wk, 0.0)
            cmd_th, cmd_tk = th.copy(), tk.copy()
            if "servo_lag" in fx:
                tau = fx["servo_lag"]["tau_s"]
                sys = signal.lti([1.0], [tau, 1.0])
                th = signal.lsim(sys, th - th[0], tf - tf[0])[1] + th[0]
                tk = signal.lsim(sys, tk - tk[0], tf - tf[0])[1] + tk[0]
                wh, wk = np.gradient(th, dtf), np.gradient(tk, dtf)
            ah, ak = np.gradient(wh, dtf), np.gradient(wk, dtf)
            flow = np.full(n_f, u)
            if "flow_unsteadiness" in fx:
                p = fx["flow_unsteadiness"]
                flow = flow * (1 + p.get("tone_fraction", 0.0)
                               * np.sin(2 * np.pi * p["tone_hz"] * tf + rng.uniform(0, 2 * np.pi)))
            if "tunnel_blockage" in fx:
                flow = flow * np.sqrt(1 + fx["tunnel_blockage"]["epsilon"])
            motion = LegMotion.from_arrays(dtf, th, tk, wh, wk, flow, ah, ak)
            w = truth.wrench(motion)[0]
            if "structural_resonance" in fx:
                p = fx["structural_resonance"]
                wn = 2 * np.pi * p["f_n_hz"]
                sys = signal.lti([wn * wn], [1.0, 2 * p["zeta"] * wn, wn * wn])
                w = np.stack([signal.lsim(sys, w[:, c] - w[0, c], tf - tf[0])[1] + w[0, c] for c in range(6)], 1)
            if "loadcell_crosstalk" in fx:
                x = np.zeros((6, 6))
                for k, v in fx["loadcell_crosstalk"].items():
                    _, to, frm = k.split("_")
                    x[SHORT.index(to), SHORT.index(frm)] = v
                w = w @ (np.eye(6) + x).T
            if "sensor_drift" in fx:
                for k, v in fx["sensor_drift"].items():
                    ch = k[len("rate_"):-len("_per_s")]
                    w[:, WRENCH_CHANNELS.index(ch)] += v * np.maximum(tf, 0.0)
            if "electrical_pickup" in fx:
                p = fx["electrical_pickup"]
                chans = p.get("channels", ["fy_n"])
                ph = rng.uniform(0, 2 * np.pi)
                for ch in chans:
                    w[:, WRENCH_CHANNELS.index(ch)] += p["amplitude_n"] * np.sin(2 * np.pi * p["f_hz"] * tf + ph)
            w = w + rng.normal(size=w.shape) * np.asarray(noise) * np.sqrt(up * rate_hz / 12.0)
            w = lowpass(w, 1.0 / dtf, 6.0, 4, axis=0)
            sl = slice(0, None, up)
            t = tf[sl]
            cth, ctk, cwh, cwk, _, _ = js.evaluate(np.maximum(t, 0.0))
            cwh, cwk = np.where(t >= 0, cwh, 0.0), np.where(t >= 0, cwk, 0.0)
            del cmd_th, cmd_tk
            d = {"campaign_id": "planted", "run_id": f"r{run:04d}", "time_s": t,
                 "flow_speed_mps": np.full(len(t), u), "theta_h_deg": cth, "theta_k_deg": ctk,
                 "omega_h_dps": cwh, "omega_k_dps": cwk}
            for c, name in enumerate(WRENCH_CHANNELS):
                d[name] = w[sl, c]
            d["interpolated"] = np.zeros(len(t), bool)
            for k, v in (("theta_h_min_deg", thmin), ("theta_h_max_deg", -100.0), ("theta_k_min_deg", 80.0),
                         ("theta_k_max_deg", tkmax), ("frequency_hz", f), ("phi_rad", phi), ("alpha_rad", 0.0)):
                d[k] = np.full(len(t), v)
            frames.append(pl.DataFrame(d))
    return pl.concat(frames)
