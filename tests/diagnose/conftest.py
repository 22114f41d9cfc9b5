"""Shared fixtures of the diagnosis tests: virtual-lab campaigns through the real ingest, generated once."""

import pytest
from diag_helpers import processed


@pytest.fixture(scope="session")
def vl_frames(tmp_path_factory):
    """``get(effects)`` -> processed frame of an EF-truth campaign with those effects planted (cached)."""
    root = tmp_path_factory.mktemp("diag-vl")
    cache = {}

    def get(effects=(), truth="ef", n_sets=12):
        key = (tuple(effects), truth, n_sets)
        if key not in cache:
            cache[key] = processed(root, effects, truth, n_sets)
        return cache[key]

    return get


@pytest.fixture(scope="session")
def null_diagnosis(vl_frames):
    """The EF diagnosed on a campaign whose truth is exactly the EF plus the rig's noise."""
    from workbench.diagnose.loop import diagnose
    from workbench.hydro.ef import EmpiricalFormula

    return diagnose(vl_frames(()), EmpiricalFormula(), "ef")
