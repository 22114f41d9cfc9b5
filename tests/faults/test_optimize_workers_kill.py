"""``workbench optimize --workers 2`` killed (SIGINT, SIGTERM, SIGKILL to its own pid) while its simulator
worker processes swim: none of its descendants survives and no result file is swapped in."""

from __future__ import annotations

import signal

import pytest
from proctree import PROJECT, Verb, project_env

pytestmark = [pytest.mark.faults, pytest.mark.slow]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGKILL], ids=["SIGINT", "SIGTERM", "SIGKILL"])
def test_killing_optimize_with_workers_leaves_no_process_and_no_output(sig, tmp_path):
    opt = Verb(["optimize", "--task", "turn", "--model", "ef", "--params", str(PROJECT / "pipelines" / "gait.yaml"),
                "--robot", str(PROJECT / "pipelines" / "robot.yaml"), "--pop", "8", "--gens", "400", "--workers", "2",
                "--no-mlflow", "--out", str(tmp_path / "gaits")], project_env(tmp_path), tmp_path, tmp_path / "opt.log")
    try:
        def workers() -> int:
            return sum("multiprocessing" in cmd and "resource_tracker" not in cmd for _, cmd in opt.seen.values())

        opt.wait_for(lambda: workers() >= 2 and "gen   2/400" in opt.text(), 240, "two workers and the second generation")
        assert "2 simulator processes" in opt.text()
        opt.kill(sig)
        assert opt.survivors(20) == []
        assert not (tmp_path / "gaits" / "turn-ef.json").exists()  # nothing half-written swapped in
    finally:
        opt.cleanup()
