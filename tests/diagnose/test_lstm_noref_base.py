"""The learned base (FED-LSTM) path of ``diagnose`` without a reference: how the model is run.

The battery's FED-LSTM no-reference results (docs/diagnose.md section 7) are measured by
``benchmarks/diagnose_battery.py --model lstm --mode noref``; the slow servo case lives in
``test_diagnose_battery.py``.
"""

from __future__ import annotations

import os


def test_a_learned_base_runs_on_the_idle_cores_and_torch_threads_are_restored():
    """Two OpenMP threads on a shared two-core machine wait on each other (demo: 8.5 min against 2.5 min)."""
    import torch  # a dependency of the workbench: a broken install fails here, it is not skipped

    from workbench.diagnose.loop import torch_threads_for_load

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with torch_threads_for_load() as n:
            assert n is not None and 1 <= n <= (os.cpu_count() or 1)
            assert torch.get_num_threads() == n
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)
