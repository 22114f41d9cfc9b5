"""The study's worker processes: started with an exact share of the trials, watched, restarted, and dying with the command.

``workbench tune --workers N`` (N > 1) runs its trials in N processes
``python -m workbench.learn.tune_workers --worker -``, each taking an exact share of ``n_trials``
so that no trial is lost or run twice (:func:`spawn_workers`). A worker's specification travels on
its stdin (nothing is written to the temp folder); the worker loads the shared study and runs
:func:`workbench.learn.tune.run_worker`. Workers die with the command (SIGINT, SIGTERM, even its
SIGKILL: :mod:`workbench.procs`); a worker killed by a signal from outside has its running trial
failed and queued again at once, by this command's process and no other while it runs (so the
retry exists before the worker's debt is counted: :mod:`workbench.learn.tune_storage`), and is
restarted for the trials of its share still owed; the retry is run by this command's workers.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from typing import Callable

#: the command line of a worker process (its specification follows on stdin)
WORKER_ARGS = ("-m", "workbench.learn.tune_workers", "--worker", "-")


def start_worker(spec: dict, worker: int, n: int, report) -> subprocess.Popen:
    """One worker process (dies with this one); its specification goes through its stdin."""
    from workbench import procs

    p = procs.popen([sys.executable, *WORKER_ARGS], stdin=subprocess.PIPE,
                    stdout=subprocess.DEVNULL, stderr=None if report else subprocess.DEVNULL)
    try:
        p.stdin.write(json.dumps({**spec, "worker": worker, "n_trials": n}).encode("utf-8"))
        p.stdin.close()
    except BrokenPipeError:  # it died at once; its exit status tells
        pass
    return p


def shares(n_trials: int, workers: int) -> dict[int, int]:
    """Worker -> its exact share of ``n_trials`` (the first ``n_trials % workers`` take one more; no empty share)."""
    share = [n_trials // workers + (1 if i < n_trials % workers else 0) for i in range(workers)]
    return {i: n for i, n in enumerate(share) if n > 0}


def _signal_name(rc: int) -> str:
    import signal

    return signal.Signals(-rc).name if -rc in signal.Signals._value2member_map_ else str(-rc)


def _owed(study, spec: dict, worker: int, share: int) -> int:
    """Trials of ``worker``'s share not finished yet (its finished ones counted by command id and worker)."""
    from workbench.learn.tune_summary import finished_trials

    mine = [t for t in finished_trials(study.get_trials(deepcopy=False))
            if t.user_attrs.get("command") == spec["command"] and t.user_attrs.get("worker") == worker]
    return share - len(mine)


def spawn_workers(spec: dict, n_trials: int, workers: int, report: Callable[[str], None] | None, study) -> None:
    """Start the worker processes with an exact share of the trials each, watch them, wait for all.

    A worker killed by a signal (not by this command) has its running trial failed and queued
    again at once, and is restarted for the trials of its share still owed (at most ``workers``
    restarts in all). Leaving by an exception (Ctrl-C, SIGTERM) stops every worker and waits.
    A worker that failed (non-zero exit status) is a :class:`~workbench.errors.StageError`.
    """
    import workbench.learn.tune_storage  # noqa: F401 - loaded before any worker starts: no import during a stop
    from workbench.errors import StageError

    say = report or (lambda _m: None)
    slots = shares(n_trials, workers)
    running: dict[int, subprocess.Popen] = {}
    codes: dict[int, int] = {}
    restarts = 0
    try:
        for i, n in slots.items():
            running[i] = start_worker(spec, i, n, report)
        while running:
            time.sleep(0.5)
            restarts = _reap(running, codes, restarts, spec, slots, workers, report, say, study)
    except BaseException:
        _stop_workers(running, study)
        raise
    bad = {i: c for i, c in codes.items() if c}
    if bad:
        raise StageError(f"tune worker(s) failed with exit status {bad}", hint="see the worker lines above")


def _reap(running: dict[int, subprocess.Popen], codes: dict[int, int], restarts: int, spec: dict,
          slots: dict[int, int], workers: int, report, say: Callable[[str], None], study) -> int:
    """One look at the running workers; returns the restarts made so far.

    An exited worker leaves ``running`` for ``codes``; a killed one that still owes trials is
    restarted in its place while ``restarts < workers``.
    """
    for i, p in list(running.items()):
        rc = p.poll()
        if rc is None:
            continue
        del running[i]
        if rc < 0:
            left = _after_kill(study, spec, i, slots[i], rc, say)
            if left > 0 and restarts < workers:
                restarts += 1
                say(f"worker {i} restarted for the {left} trial(s) of its share still owed")
                running[i] = start_worker(spec, i, left, report)
                continue
            if left <= 0:  # killed after its share was done (while exiting): nothing is owed
                say(f"worker {i} had finished its {slots[i]} trial(s); nothing owed")
                codes[i] = 0
                continue
        codes[i] = rc
    return restarts


def _after_kill(study, spec: dict, worker: int, share: int, rc: int, say: Callable[[str], None]) -> int:
    """A worker was killed by a signal: fail and queue again its running trial, say so; returns the trials it owes."""
    from workbench.learn.tune_storage import fail_stale

    failed = fail_stale(study)
    left = _owed(study, spec, worker, share)
    say(f"worker {worker} was killed ({_signal_name(rc)}); trial(s) {failed or 'none'} failed and queued again")
    return left


def _stop_workers(running: dict[int, subprocess.Popen], study) -> None:
    """Leaving by an exception: mark the stop, end the running workers and wait, fail their trials (if the storage can)."""
    from workbench import procs
    from workbench.learn.tune_storage import fail_stale

    procs.interrupted()
    procs.stop(list(running.values()))
    try:
        fail_stale(study)
    except Exception:  # noqa: BLE001 - the storage itself may be what failed
        pass


def worker_main(argv: list[str]) -> int:
    """``python -m workbench.learn.tune_workers --worker SPEC.json|-``: run one worker's share of the trials."""
    from workbench import procs
    from workbench.console import info
    from workbench.contract.jsonfile import read_json
    from workbench.errors import WorkbenchError
    from workbench.learn.tune import run_worker

    if len(argv) != 2 or argv[0] != "--worker":
        print("usage: python -m workbench.learn.tune_workers --worker SPEC.json|-  (- reads the spec from stdin)",
              file=sys.stderr)
        return 2
    procs.install()  # SIGTERM (also sent when the command dies) fails the running trial cleanly
    try:
        spec = json.loads(sys.stdin.read()) if argv[1] == "-" else read_json(argv[1], "worker specification")
        run_worker(spec, info)
    except WorkbenchError as exc:
        print(f"error: {exc.format()}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(worker_main(sys.argv[1:]))
