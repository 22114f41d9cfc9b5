"""`python -m workbench` runs the CLI (issue 15.7)."""
import subprocess
import sys


def test_python_dash_m_workbench_runs_the_cli():
    out = subprocess.run([sys.executable, "-m", "workbench", "--help"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "the daily loop" in out.stdout and "diagnose" in out.stdout
