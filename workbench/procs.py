"""No process outlives its command: child processes that die with their parent, on any signal.

A verb that starts processes uses this module, so that SIGINT (Ctrl-C), SIGTERM and even the
parent's SIGKILL leave nothing running:

- :func:`die_with_parent` asks Linux to send the calling process SIGTERM when its parent dies
  (``prctl(PR_SET_PDEATHSIG)``, via ctypes). It is called in each child: as ``preexec_fn`` of
  :func:`popen` (it survives ``exec``), or as the ``initializer`` of :func:`process_pool`.
  A child started just as its parent died notices the new parent and stops itself.
- :func:`popen` starts a child that dies with its parent and is remembered; :func:`stop` ends
  it (SIGTERM to its process group, then SIGKILL after a grace period) and waits for it.
- ``python -m workbench.procs guard -- CMD...`` runs CMD under a guard for programs that start
  their own children and do not stop them (``mlflow server``: uvicorn, a job runner, workers):
  the guard dies with its parent, adopts every orphan of the tree (``PR_SET_CHILD_SUBREAPER``),
  and on SIGTERM/SIGINT/SIGHUP, or when CMD ends, ends the whole tree and waits for it.
- :func:`install` turns SIGTERM and SIGHUP into ``KeyboardInterrupt`` in the main thread, so the
  same cleanup as Ctrl-C runs (``finally`` blocks, temporary files, children stopped and waited
  for); a second signal during that cleanup kills the remembered children at once and exits.
- :func:`process_pool` is a ``ProcessPoolExecutor`` (spawn) whose workers die with the parent and
  that, when the block is left by an exception (Ctrl-C included), cancels what is queued and ends
  its workers instead of waiting for every queued job.

On other systems than Linux the parent-death signal is unavailable: the signal handling and the
explicit stops still apply.
"""

from __future__ import annotations

import atexit
import os
import signal
import subprocess
import sys
import threading
import time
from contextlib import contextmanager
from typing import Iterator, Sequence

PR_SET_PDEATHSIG = 1
PR_SET_CHILD_SUBREAPER = 36

#: how long a stopped child may take to exit after SIGTERM before it gets SIGKILL
GRACE_S = 10.0

_children: list[subprocess.Popen] = []
_installed = False
_stopping = False


def _libc():
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    try:
        return ctypes.CDLL(None, use_errno=True)
    except OSError:
        return None


_LIBC = _libc()


def die_with_parent(sig: int = signal.SIGTERM, parent_pid: int | None = None) -> bool:
    """Have the calling process receive ``sig`` when its parent dies (Linux); True when set.

    ``parent_pid``: the expected parent; if it is already gone (the parent died before this
    call), the process sends itself ``sig`` at once.
    """
    if _LIBC is None:
        return False
    ok = _LIBC.prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    if parent_pid is not None and os.getppid() != parent_pid:
        os.kill(os.getpid(), sig)
    return ok


def become_subreaper() -> bool:
    """Adopt orphaned descendants (Linux), so they can still be found and ended; True when set."""
    if _LIBC is None:
        return False
    return _LIBC.prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0


def _preexec(parent_pid: int, new_group: bool):
    def setup() -> None:  # runs in the child between fork and exec
        if new_group:
            os.setpgid(0, 0)
        die_with_parent(signal.SIGTERM, parent_pid)

    return setup


def popen(cmd: Sequence[str], *, new_group: bool = True, **kwargs) -> subprocess.Popen:
    """``subprocess.Popen`` of a child that dies with this process and is stopped by :func:`stop_all`.

    ``new_group``: the child leads its own process group (default), so :func:`stop` reaches the
    processes it starts too, and a terminal's Ctrl-C reaches it only through this process.
    """
    if "preexec_fn" in kwargs or "start_new_session" in kwargs:
        raise TypeError("popen sets the child's process group and parent-death signal itself")
    proc = subprocess.Popen(list(cmd), preexec_fn=_preexec(os.getpid(), new_group), **kwargs)
    proc._wb_group = new_group  # type: ignore[attr-defined]
    _children.append(proc)
    return proc


def _signal_tree(proc: subprocess.Popen, sig: int) -> None:
    """``sig`` to the child's process group (when it leads one) and to the child itself."""
    if proc.poll() is not None:
        return
    if getattr(proc, "_wb_group", False):
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass
    try:
        proc.send_signal(sig)
    except (ProcessLookupError, OSError):
        pass


def stop(procs: Sequence[subprocess.Popen] | subprocess.Popen, grace_s: float = GRACE_S) -> list[int | None]:
    """End children: SIGTERM (their groups too), SIGKILL after ``grace_s``; waits; returns their exit codes."""
    procs = [procs] if isinstance(procs, subprocess.Popen) else list(procs)
    for p in procs:
        _signal_tree(p, signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    for p in procs:
        try:
            p.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            _signal_tree(p, signal.SIGKILL)
            p.wait()
        if getattr(p, "_wb_group", False):  # anything left in its group (it led the group)
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        if p in _children:
            _children.remove(p)
    return [p.returncode for p in procs]


def stop_all(grace_s: float = GRACE_S) -> None:
    """Stop every child started by :func:`popen` that is still running."""
    if _children:
        stop(list(_children), grace_s)


def _on_signal(signum, frame):
    global _stopping
    if _stopping:  # a second signal while cleaning up: no more waiting
        for p in list(_children):
            _signal_tree(p, signal.SIGKILL)
        os._exit(128 + signum)
    _stopping = True
    raise KeyboardInterrupt(signal.Signals(signum).name)


def install() -> None:
    """SIGTERM and SIGHUP raise ``KeyboardInterrupt`` in the main thread (cleanup as for Ctrl-C); children stopped at exit.

    Call once, early, from the main thread of a command. A second SIGINT/SIGTERM/SIGHUP while
    the first is being handled kills the remembered children and exits at once.
    """
    global _installed
    if _installed or threading.current_thread() is not threading.main_thread():
        return
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, _on_signal)
    atexit.register(stop_all)
    _installed = True


def interrupted() -> None:
    """Mark that a stop is under way (a later signal then exits at once); used by handlers of KeyboardInterrupt."""
    global _stopping
    _stopping = True


@contextmanager
def deferred_signals() -> Iterator[None]:
    """Hold SIGINT, SIGTERM and SIGHUP until the block ends, then act on the first that came.

    For a few steps that must happen together or not at all (a trial created in the study and its
    owner recorded): a signal arriving inside the block runs its handler (``KeyboardInterrupt``,
    usually) only after the block, never half-way through it. Outside the main thread (where
    Python cannot change handlers) the block runs unprotected.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    sigs = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    old = {s: signal.signal(s, lambda signum, _frame: pending.append(signum)) for s in sigs}
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        if pending:
            first = pending[0]
            handler = old[first]
            if callable(handler):
                handler(first, None)
            elif handler == signal.SIG_DFL:
                os.kill(os.getpid(), first)


# ---------------------------------------------------------------------------------------------
# process pools


def pool_initializer(parent_pid: int, then=None, *args) -> None:
    """``ProcessPoolExecutor`` initializer: die with the parent, ignore Ctrl-C (the parent decides), then ``then(*args)``."""
    die_with_parent(signal.SIGTERM, parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if then is not None:
        then(*args)


@contextmanager
def process_pool(workers: int, initializer=None, initargs: tuple = ()) -> Iterator:
    """A spawn ``ProcessPoolExecutor`` whose workers die with this process and end with the block on an error.

    Leaving the block normally waits for the work as usual; leaving it by an exception
    (Ctrl-C, SIGTERM after :func:`install`, a failed job) cancels the queued jobs, ends the
    worker processes (SIGTERM, then SIGKILL) and waits for them, instead of running the queue out.
    """
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    ex = ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"), initializer=pool_initializer,
                             initargs=(os.getpid(), initializer, *initargs))
    try:
        yield ex
    except BaseException:
        procs = list((getattr(ex, "_processes", None) or {}).values())
        ex.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            if p.is_alive():
                p.terminate()
        deadline = time.monotonic() + GRACE_S
        for p in procs:
            p.join(max(0.0, deadline - time.monotonic()))
            if p.is_alive():
                p.kill()
                p.join()
        raise
    else:
        ex.shutdown(wait=True)


# ---------------------------------------------------------------------------------------------
# the guard: python -m workbench.procs guard -- CMD...


def _descendants() -> list:
    import psutil

    try:
        return psutil.Process().children(recursive=True)
    except psutil.Error:
        return []


def _end_tree(child: subprocess.Popen, grace_s: float) -> None:
    """SIGTERM to the child's group and every descendant, SIGKILL after ``grace_s``, reap all."""
    import psutil

    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(child.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass
        procs = _descendants()
        for p in procs:
            try:
                p.send_signal(sig)
            except psutil.Error:
                pass
        gone, alive = psutil.wait_procs(procs, timeout=grace_s if sig == signal.SIGTERM else 5.0)
        if not alive and child.poll() is not None:
            break
    child.poll()
    # reap adopted orphans that exited meanwhile
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            break
        if pid == 0:
            break


def guard_main(cmd: Sequence[str], grace_s: float = GRACE_S) -> int:
    """Run ``cmd`` and end its whole process tree with it (see the module text); returns its exit status."""
    become_subreaper()
    stop_sig = []

    def handler(signum, frame):
        stop_sig.append(signum)

    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, handler)
    child = subprocess.Popen(list(cmd), preexec_fn=_preexec(os.getpid(), True))
    try:
        while child.poll() is None and not stop_sig:
            time.sleep(0.2)
    finally:
        _end_tree(child, grace_s)
    if stop_sig:
        return 128 + stop_sig[0]
    return child.returncode if child.returncode >= 0 else 128 - child.returncode


def guarded(cmd: Sequence[str]) -> list[str]:
    """The command line that runs ``cmd`` under the guard (for :func:`popen`)."""
    return [sys.executable, "-m", "workbench.procs", "guard", "--", *cmd]


if __name__ == "__main__":
    argv = sys.argv[1:]
    if len(argv) < 3 or argv[0] != "guard" or argv[1] != "--":
        print("usage: python -m workbench.procs guard -- CMD [ARGS...]", file=sys.stderr)
        sys.exit(2)
    # the guard itself dies with the command that started it (popen set that before exec)
    sys.exit(guard_main(argv[2:]))
