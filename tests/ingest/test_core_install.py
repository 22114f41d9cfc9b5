"""Issue 15.7: the acquisition station's core (contract, validate, ingest, acquire) runs without the full
stack. The heavy libraries are blocked in a fresh interpreter (an import of any of them fails), and the
core verbs run end to end on a campaign written by the test's own fixture."""

from __future__ import annotations

import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest
from ingest_fixtures import RunPlan, write_campaign

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("torch", "lightning", "mlflow", "optuna", "cv2", "pymoo", "dvc", "psycopg2")

BLOCKED_RUN = textwrap.dedent("""
    import importlib.machinery
    import sys
    heavy = {heavy!r}

    class Missing:  # importing the module fails, as on a machine without it
        def create_module(self, spec):
            raise ImportError(f"{{spec.name}} is not installed on the acquisition station")

        def exec_module(self, module):
            pass

    class Block:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in heavy:
                return importlib.machinery.ModuleSpec(name, Missing())
            return None

    sys.meta_path.insert(0, Block())
    from workbench.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def _core(args, cwd):
    code = BLOCKED_RUN.format(heavy=HEAVY)
    return subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_core_dependencies_leave_the_full_stack_to_an_extra():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    core = " ".join(meta["dependencies"]).lower()
    for lib in ("torch", "lightning", "mlflow", "optuna", "opencv", "pymoo", "dvc"):
        assert lib not in core, f"{lib} is a core dependency"
    full = " ".join(meta["optional-dependencies"]["full"]).lower()
    assert all(lib in full for lib in ("torch", "lightning", "mlflow", "optuna", "opencv", "pymoo", "dvc"))
    assert "'.[full,dev]'" in (ROOT / "Makefile").read_text()


@pytest.mark.slow
def test_validate_ingest_and_acquire_run_with_the_heavy_libraries_blocked(tmp_path):
    camp = write_campaign(tmp_path / "c1", [RunPlan("r1", flow_speed=0.1), RunPlan("r2", flow_speed=0.2)])
    out = _core(["campaign", "validate", str(camp)], tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    out = _core(["ingest", str(camp), "--out", str(tmp_path / "c1.parquet")], tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert (tmp_path / "c1.parquet").stat().st_size > 1000
    out = _core(["acquire", "--port", "loop://", "--out", str(tmp_path / "r1.loadcell.bin"), "--duration", "0.5"],
                tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    # and the block is real: a verb of the full stack fails on it
    out = _core(["train", "--config", str(ROOT / "pipelines" / "learn.yaml"), "--data", str(tmp_path / "c1.parquet"),
                 "--no-mlflow", "--out", str(tmp_path / "m")],
                tmp_path)
    assert out.returncode != 0 and "not installed on the acquisition station" in out.stdout + out.stderr
