"""A faithful processed towing-tank frame (contract section 3) built from the paper's drag polynomials.

Used until the virtual lab's towing tank and ingest are available, and to plant known drag laws.
"""

import numpy as np
import polars as pl

PAPER = {"forward": (9.997, -0.132, 0.334), "lateral": (15.571, 0.937, 0.055)}
SPEEDS = (0.10, 0.15, 0.20, 0.25, 0.30, 0.35)


def carriage_profile(speed, rate_hz=100.0, accel=0.25, track_m=3.0, rest_s=1.5):
    """Rest, constant acceleration, cruise, deceleration, rest: time, position, speed, acceleration."""
    t_acc = speed / accel
    d_acc = 0.5 * accel * t_acc**2
    t_cruise = (track_m - 2 * d_acc) / speed
    total = 2 * rest_s + 2 * t_acc + t_cruise
    t = np.arange(0.0, total, 1.0 / rate_hz)
    tau = t - rest_s
    a = np.where((tau >= 0) & (tau < t_acc), accel, 0.0)
    a = np.where((tau >= t_acc + t_cruise) & (tau < 2 * t_acc + t_cruise), -accel, a)
    v = np.clip(np.cumsum(a) / rate_hz, 0.0, speed)
    x = np.cumsum(v) / rate_hz
    return t, x, v, a


def towing_frame(coeffs=PAPER, speeds=SPEEDS, repeats=1, noise_n=0.02, speed_noise=0.002, added_mass_kg=1.0,
                 seed=0, heading_column=True, campaign_id="towing-fixture"):
    rng = np.random.default_rng(seed)
    frames = []
    k = 0
    for heading in ("forward", "lateral"):
        c2, c1, c0 = coeffs[heading]
        for _rep in range(repeats):
            for v_nom in speeds:
                k += 1
                t, x, v, a = carriage_profile(v_nom)
                drag = np.where(v > 0.005, c2 * v**2 + c1 * v + c0, 0.0)
                noise = np.convolve(rng.normal(0, noise_n * np.sqrt(5), t.size), np.ones(5) / 5, mode="same")
                along = -drag - added_mass_kg * a + noise
                other = np.convolve(rng.normal(0, noise_n * np.sqrt(5), t.size), np.ones(5) / 5, mode="same")
                fx, fy = (other, along) if heading == "forward" else (along, other)
                cols = {
                    "campaign_id": [campaign_id] * t.size, "run_id": [f"t{k:03d}"] * t.size, "time_s": t,
                    "flow_speed_mps": np.full(t.size, v_nom), "position_m": x,
                    "speed_mps": v + rng.normal(0, speed_noise, t.size),
                    "fx_n": fx, "fy_n": fy, "fz_n": rng.normal(0, noise_n, t.size),
                    "tx_nm": np.zeros(t.size), "ty_nm": np.zeros(t.size), "tz_nm": np.zeros(t.size),
                    "interpolated": np.zeros(t.size, bool),
                }
                if heading_column:
                    cols["heading"] = [heading] * t.size
                frames.append(pl.DataFrame(cols))
    return pl.concat(frames)


def _sync(tc, start):
    """The rig's trigger line on the controller clock: raised at the start and every 1.000 s for 0.1 s."""
    rel = tc - start
    return ((rel >= 0) & (np.mod(rel, 1.0) < 0.1)).astype(int)


def write_raw_towing_campaign(root, coeffs=PAPER, speeds=(0.10, 0.20, 0.30, 0.35), noise_n=0.01, seed=0,
                              campaign_id=None, ctrl_hz=50.0, lc_hz=200.0):
    """A towing-tank campaign folder per data contract section 1 (CSV pairs), drag from known polynomials.

    Carriage log on the controller clock; load cell on its own clock (offset and drift), both
    sampling the shared trigger line. The load cell reads the hydrodynamic force on the robot.
    """
    from pathlib import Path

    rng = np.random.default_rng(seed)
    root = Path(root)
    cid = campaign_id or root.name
    (root / "runs").mkdir(parents=True, exist_ok=True)
    runs = []
    k = 0
    for heading in ("forward", "lateral"):
        c2, c1, c0 = coeffs[heading]
        for v_nom in speeds:
            k += 1
            rid = f"{heading[0]}{k:02d}"
            t, x, v, a = carriage_profile(v_nom, rate_hz=ctrl_hz, accel=0.4, track_m=2.0, rest_s=2.0)
            start = t[int(ctrl_hz * 1.0)]  # the run starts (trigger raised) 1 s before the carriage moves
            carriage = np.column_stack([t, x, _sync(t, start)])
            np.savetxt(root / "runs" / f"{rid}.carriage.csv", carriage, delimiter=",", fmt=["%.5f", "%.6f", "%d"],
                       header="time_s,position_m,sync", comments="")
            offset, drift = rng.uniform(5, 50), rng.uniform(-2e-5, 2e-5)
            t_lc = np.arange(offset, offset + (t[-1] - 0.01) * (1 + drift), 1.0 / lc_hz)
            tc = (t_lc - offset) / (1 + drift)
            vv = np.interp(tc, t, v)
            aa = np.interp(tc, t, a)
            along = -np.where(vv > 0.005, c2 * vv**2 + c1 * vv + c0, 0.0) - 0.5 * aa
            wrench = rng.normal(0, noise_n, (t_lc.size, 6)) * [1, 1, 1, 0.01, 0.01, 0.01]
            wrench[:, 1 if heading == "forward" else 0] += along
            data = np.column_stack([t_lc, wrench, _sync(tc, start)])
            np.savetxt(root / "runs" / f"{rid}.loadcell.csv", data, delimiter=",", fmt=["%.6f"] + ["%.6f"] * 6 + ["%d"],
                       header="time_s,fx_n,fy_n,fz_n,tx_nm,ty_nm,tz_nm,sync", comments="")
            runs.append(f'[[runs]]\nid = "{rid}"\nflow_speed_mps = {v_nom}\nheading = "{heading}"\n'
                        f'loadcell = "runs/{rid}.loadcell.csv"\ncarriage = "runs/{rid}.carriage.csv"\n')
    (root / "campaign.toml").write_text(
        f'schema = "workbench/campaign@1"\nid = "{cid}"\nfacility = "towing_tank"\ndate = 2025-05-01\n'
        'description = "test fixture: drag from known polynomials"\n\n[loadcell]\nmodel = "DMI D6095XA"\n'
        f"rate_hz = {lc_hz}\n\n" + "\n".join(runs))
    return root
