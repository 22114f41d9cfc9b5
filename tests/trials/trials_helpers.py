"""Helpers for the trials tests: small, fast virtual-pool trials and the ground truth."""

import json

from workbench.virtual_lab.pool import PoolTrial, circle_path, straight_path

#: small, fast videos for the bad-input and shape tests; the robot swims fast so trials are short
SMALL = dict(width_px=480, height_px=270, fps=15.0, start_s=0.53, post_s=1.0, occlusion_fraction=0.0, workers=1,
             glare_patches=1, straight_start=(1.2, 1.2, 0.0), turn_start=(1.2, 2.5, 20.0))


def fast_straight(tid, model="EF", solution=1, **kw):
    t, x, y, yaw = straight_path(speed_mps=0.3, drift_deg=8, duration_s=12)
    return PoolTrial(tid, "straight", model, solution, t, x, y, yaw, **kw)


def fast_turn(tid, model="EF", solution=1, **kw):
    t, x, y, yaw = circle_path(radius_m=0.1, period_s=6, duration_s=12, ramp_s=1.0)
    return PoolTrial(tid, "turn", model, solution, t, x, y, yaw, **kw)


def truth_of(folder):
    return json.loads((folder / "truth.json").read_text())["trials"]
