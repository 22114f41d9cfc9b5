"""How many torch threads to use: a number, torch's default, or ``auto`` (the cores idle right now).

On a 2-core machine two torch threads train the LSTM about 1.6x faster than one when the
machine is idle, and 1.6x slower when another process holds a core (OpenMP threads wait on
each other whenever one is descheduled; measured, docs/learning.md). ``auto`` therefore looks
at how busy the cores are at the moment a stage starts, not at the load average, which still
counts the stage that just ended.
"""

from __future__ import annotations

import os

from workbench.errors import SettingError

AUTO = "auto"


def check_setting(value) -> int | str | None:
    """Validate a ``torch_threads`` setting: a positive integer, ``auto`` or null (torch's default)."""
    if value is None or value == AUTO:
        return value
    if isinstance(value, bool) or not isinstance(value, (int, str)) or not str(value).isdigit() or int(value) < 1:
        raise SettingError(f"torch_threads must be a positive integer, 'auto' or null, not {value!r}")
    return int(value)


def idle_cores(sample_s: float = 0.5) -> int:
    """Cores this process may use that stood idle over the last ``sample_s`` seconds (at least 1)."""
    import psutil

    busy = psutil.cpu_percent(interval=sample_s, percpu=True)
    if hasattr(os, "sched_getaffinity"):  # only the cores this process may run on
        busy = [busy[i] for i in sorted(os.sched_getaffinity(0)) if i < len(busy)] or busy
    usable = len(busy)
    # idle capacity summed over cores, counted in whole cores that are at least 3/4 free
    free = sum(max(0.0, 1.0 - b / 100.0) for b in busy)
    return max(1, min(usable, int(free + 0.25)))


def resolve(value) -> int | None:
    """The thread count a setting means now (None: leave torch's default)."""
    value = check_setting(value)
    return idle_cores() if value == AUTO else value


def apply_torch_threads(value) -> int | None:
    """Set torch's intra-op threads from a setting; returns the number set (None: untouched)."""
    n = resolve(value)
    if n is not None:
        import torch

        torch.set_num_threads(n)
    return n
