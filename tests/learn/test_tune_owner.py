"""A running worker is not taken for dead when another process reads its start time a second off.

psutil's ``create_time`` is the start since boot plus Linux's boot time, which ``/proc/stat`` gives in
whole seconds of the wall clock: after a clock correction a process reads another's start a second
later or earlier than that process recorded it. ``make test`` (1 Dec 2026) had one tune command fail
the other's running trial that way. The owner records here are the test's own.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys

import psutil

from workbench.learn.tune_storage import START_TOLERANCE_S, owner_is_dead


def _me(shift_s: float = 0.0) -> dict:
    return {"host": socket.gethostname(), "pid": os.getpid(), "ctime": psutil.Process().create_time() + shift_s}


def test_a_live_owner_read_a_second_off_is_alive():
    assert not owner_is_dead(_me())
    assert not owner_is_dead(_me(+1.0)) and not owner_is_dead(_me(-1.0))  # btime moved by one whole second
    assert START_TOLERANCE_S < 5.0  # still far below any time in which the PID space goes round


def test_a_reused_pid_and_a_gone_process_are_dead():
    # the PID lives, but started long after the owner did: another process under a reused PID
    assert owner_is_dead(_me(-3600.0))
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    assert owner_is_dead({"host": socket.gethostname(), "pid": gone.pid, "ctime": 0.0})
    # another machine's process is never judged from here
    assert not owner_is_dead({"host": "elsewhere.invalid", "pid": gone.pid, "ctime": 0.0})
