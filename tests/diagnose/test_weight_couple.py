"""``weight_buoyancy_couple``: equal and opposite vertical loads apart along the leg give tx only.

The expected wrench is written here from r x F of two leg-plane point loads (weight down at one
distance along the hip-to-Q line, buoyancy up at another, both at the web's lateral offset); the
leg's pose comes from the joint angles alone.
"""

import numpy as np
import pytest

from workbench.diagnose.chain import Active, Configuration, build_design
from workbench.diagnose.effects.fluid import WeightBuoyancyCouple
from workbench.hydro.kinematics import DEFAULT_GEOMETRY as G
from workbench.hydro.kinematics import leg_state
from workbench.hydro.motion import JointSinusoid, LegMotion


class _Batch:
    def __init__(self, motion):
        self.motion = motion
        self.dt_s = motion.dt_s
        self.time_s = np.broadcast_to(np.arange(motion.shape[1]) * motion.dt_s, motion.shape)


class _Still:
    """A model that predicts nothing (only the effect's column matters here)."""

    def wrench(self, motion):
        return np.zeros(motion.shape + (6,))


def _point(fy, px, x_off):
    """Load-cell wrench of a vertical leg-plane force ``fy`` at leg-plane X ``px``, ``x_off`` off the hip axis."""
    z = 0 * fy
    return np.stack([z, z, fy, px * fy, -x_off * fy, z], -1)


def test_a_couple_of_weight_and_buoyancy_is_tx_only_and_turns_with_the_leg():
    t = np.arange(0, 3, 1 / 65)
    th, tk, wh, wk, ah, ak = JointSinusoid(-10.0, -100.0, 80.0, -40.0, 0.5, 2.0, 0.0).evaluate(t)
    motion = LegMotion.from_arrays(1 / 65, th, tk, wh, wk, np.full_like(th, 0.12), ah, ak)
    q = leg_state(np.radians(th), np.radians(tk), geometry=G).q
    x = G.web_offset_x_m
    length = np.sqrt(x * x + q[:, 0] ** 2 + q[:, 1] ** 2)
    weight, r_g, r_b = 1.5, 0.05, 0.08             # N; centres of mass and of buoyancy along the line (m)
    expected = (_point(np.full_like(th, -weight), r_g * q[:, 0] / length, x)
                + _point(np.full_like(th, weight), r_b * q[:, 0] / length, x))
    couple = weight * (r_b - r_g)                 # N m, + when buoyancy acts further out
    d = build_design(_Still(), _Batch(motion), Configuration([Active(WeightBuoyancyCouple(), {})]))
    col = d.cols[d.names.index("weight_buoyancy_couple.couple_nm")][0]
    assert np.abs(expected[:, [0, 1, 2, 4, 5]]).max() == pytest.approx(0.0, abs=1e-12)  # no net force, no ty
    np.testing.assert_allclose(couple * col, expected, atol=1e-12)
    assert np.ptp(expected[:, 3]) > 0.3 * couple                 # it turns with the leg
