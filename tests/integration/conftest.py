"""Fixtures for integration tests: a small processed tunnel campaign from the virtual lab."""

import pytest


@pytest.fixture(scope="session")
def small_processed(tmp_path_factory):
    """A small virtual-lab tunnel campaign, ingested: 8 parameter sets x 2 speeds x 3 cycles."""
    from workbench.ingest import ingest_campaign, write_processed
    from workbench.virtual_lab.tunnel import generate_tunnel

    root = tmp_path_factory.mktemp("itest-data")
    camp = generate_tunnel(root / "raw" / "itest-tunnel", seed=3, cycles=3, flow_speeds=[0.0, 0.2],
                           grid={"theta_h_min_deg": [10.0, -50.0], "theta_k_max_deg": [-20.0, -60.0],
                                 "frequency_hz": [0.4, 0.6], "phi_rad": [1.0472]})
    out = root / "processed" / "itest-tunnel.parquet"
    write_processed(ingest_campaign(camp), out)
    return out
