"""Helpers for the fault suite: the real CLI in a subprocess, killed with SIGKILL at a chosen moment."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: what our temporaries look like (workbench.atomic); none may be left after the next complete run
OUR_TEMP = re.compile(r"^\..+\.wb\d+-[0-9a-f]{8}\.(tmp|part|old|set)")


def cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Run ``workbench ARGS`` to the end; stdout and stderr captured."""
    env = dict(os.environ, MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1")
    return subprocess.run([sys.executable, "-m", "workbench.cli", *args], cwd=cwd or ROOT, env=env,
                          capture_output=True, text=True, timeout=600)


def timed_cli(*args: str) -> float:
    """Run to the end (must succeed); return its wall time."""
    t0 = time.perf_counter()
    r = cli(*args)
    assert r.returncode == 0, r.stderr[-2000:]
    return time.perf_counter() - t0


def kill_after(delay_s: float, *args: str, env: dict | None = None, cwd: Path | None = None) -> int | None:
    """Start ``workbench ARGS`` in its own process group, SIGKILL the group after ``delay_s``.

    Returns the exit status when the command ended before the kill, else None. ``env`` and ``cwd``
    default to this checkout with the test environment's variables.
    """
    env = env or dict(os.environ, MPLBACKEND="Agg", OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-m", "workbench.cli", *args], cwd=cwd or ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        proc.wait(timeout=delay_s)
        return proc.returncode
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        return None


def leftovers(folder: Path) -> list[str]:
    """Our temporaries under ``folder`` (recursively).

    ``os.walk`` skips a folder that vanishes while it is read (a verb renaming its temporary folder into
    place as we look): ``Path.rglob`` raised FileNotFoundError there, failing a kill test on a race of its own.
    """
    found = []
    for root, dirs, files in os.walk(folder):
        found += [os.path.join(root, n) for n in (*dirs, *files) if n.startswith(".") and OUR_TEMP.match(n)]
    return sorted(found)


def kill_moments(rng, full_s: float, n: int) -> list[float]:
    """``n`` moments spread over a run's length: one early (start-up), the rest uniform over the run."""
    return [0.3 + rng.random() * 0.5] + [rng.uniform(0.5, 1.05 * full_s) for _ in range(n - 1)]
