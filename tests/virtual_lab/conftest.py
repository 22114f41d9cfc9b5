"""Small virtual-lab campaigns shared by the tests (session scope: generated once)."""

import pytest
from vl_helpers import small_tunnel

from workbench.virtual_lab.towing import generate_towing


@pytest.fixture(scope="session")
def tunnel_csv(tmp_path_factory):
    return small_tunnel(tmp_path_factory.mktemp("vl") / "tun-csv", seed=1)


@pytest.fixture(scope="session")
def tunnel_mixed(tmp_path_factory):
    """Same seed as tunnel_csv, all three forms, feedback columns, .bin faults."""
    return small_tunnel(tmp_path_factory.mktemp("vl") / "tun-mixed", seed=1, form="mixed", feedback=True,
                        bin_faults=True)


@pytest.fixture(scope="session")
def towing_csv(tmp_path_factory):
    return generate_towing(tmp_path_factory.mktemp("vl") / "tow-csv", seed=2,
                           speeds=(0.1, 0.15, 0.2, 0.25, 0.3, 0.35))
