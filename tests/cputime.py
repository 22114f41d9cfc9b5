"""A pytest plugin: each test's CPU time (this process + the children it waited for), for `slow` decisions.

    PYTHONPATH=tests CPUTIME_OUT=/tmp/cpu.tsv python -m pytest -q -m "not slow" -p cputime
    sort -t$'\\t' -k2 -rn /tmp/cpu.tsv | head     # node id, CPU s, wall s, load average (1 min)

Wall time on a shared machine is mostly waiting for other work; CPU time is what a test costs on an
idle one (docs/testing.md). Setup and teardown count with the test (a module fixture with its first user).
"""

import os
import resource
import time

import pytest


def _cpu() -> float:
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    c0, w0 = _cpu(), time.perf_counter()
    yield
    out = os.environ.get("CPUTIME_OUT")
    if out:
        with open(out, "a") as f:
            f.write(f"{item.nodeid}\t{_cpu() - c0:.3f}\t{time.perf_counter() - w0:.3f}\t{os.getloadavg()[0]:.2f}\n")
