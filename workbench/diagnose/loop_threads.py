"""The diagnosis's use of the machine: BLAS and torch threads, and batch size for an expensive model.

Context managers the loop runs under (one BLAS thread for thousands of small products; torch's
threads set to the idle cores while a learned model runs) and the probe that picks smaller run
batches for a model whose every tick costs a network run.
"""

from __future__ import annotations

import contextlib
import sys

import numpy as np

from workbench.diagnose.data import DataSettings
from workbench.diagnose.problem import FitSettings, expensive, us_per_tick


def one_blas_thread():
    """Run small linear algebra on one BLAS thread.

    The diagnosis does thousands of small matrix products; a multi-threaded BLAS on a shared
    two-core machine spends up to a thousand times longer synchronising its threads than
    computing them (measured: 70 ms instead of 0.05 ms for a 1500 x 25 Gram matrix).
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - an optional speed-up
        import contextlib

        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


@contextlib.contextmanager
def torch_threads_for_load():
    """Torch's intra-op threads set to the cores idle now (``workbench.threads`` ``auto``), restored after.

    Only when torch is already loaded (a learned base model such as the FED-LSTM); an EF
    diagnosis never imports it. Two OpenMP threads on a two-core machine that other jobs share
    wait on each other whenever one is descheduled: profiled on the demo campaign under a load
    average of 13, ``torch.lstm`` took 160 s of wall time for a run whose whole process used
    84 s of CPU. One thread per idle core keeps the model runs compute-bound.
    """
    torch = sys.modules.get("torch")
    if torch is None:
        yield None
        return
    from workbench.threads import resolve

    old = torch.get_num_threads()
    n = resolve("auto")
    torch.set_num_threads(n)
    try:
        yield n
    finally:
        torch.set_num_threads(old)


def _chunks_for(model, data: DataSettings) -> DataSettings:
    """Smaller batches for an expensive model: every padded tick costs a model run (a 32-step LSTM)."""
    import dataclasses

    from workbench.hydro.motion import LegMotion

    n = 256
    z = np.zeros((2, n))
    probe = LegMotion(1 / 65, z - 40.0, z + 40.0, z, z, z + 0.1, z, z)
    # the same rule and timing as the searches' surrogate (problem.expensive): a window net is expensive whatever
    # the load
    try:
        costly = expensive(model, lambda: us_per_tick(model, probe), FitSettings().expensive_us_per_tick)[0]
    except Exception:  # noqa: BLE001 - a model that cannot run a probe is diagnosed as configured
        return data
    if costly and data.chunk_runs > 12:
        return dataclasses.replace(data, chunk_runs=12)
    return data
