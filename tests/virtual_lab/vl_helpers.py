"""Helpers shared by the virtual-lab tests (a unique module name: tests/ has no packages)."""

import math

from workbench.virtual_lab.tunnel import generate_tunnel

SMALL_GRID = [
    {"theta_h_min_deg": 10.0, "theta_k_max_deg": -20.0, "frequency_hz": 0.6, "phi_rad": math.pi / 3},
    {"theta_h_min_deg": -50.0, "theta_k_max_deg": -60.0, "frequency_hz": 0.5, "phi_rad": math.pi},
    {"theta_h_min_deg": -30.0, "theta_k_max_deg": -40.0, "frequency_hz": 0.6, "phi_rad": 5 * math.pi / 3},
]
SMALL = dict(grid=SMALL_GRID, flow_speeds=(0.0, 0.2), cycles=2)


def small_tunnel(path, **kw):
    """A 6-run tunnel campaign (3 parameter sets x 2 flow speeds x 2 cycles)."""
    return generate_tunnel(path, **{**SMALL, **kw})
