"""The study's storage: where it lives, its lock, heartbeats that fail dead workers' trials, per-trial seeds.

**Where.** :func:`resolve_storage` opens the storage of a study: by default an Optuna journal file
``.optuna/<study>.journal`` at the project root (its folder made here: this module is learn's I/O
edge for the study's storage), a ``*.journal`` path, or any Optuna storage URL (``postgresql://...``
for a cluster). The journal file is locked with an ``open()``-based lock (works on local disks and
NFS alike). :func:`fail_stale` fails a study's stale RUNNING trials now.

**Heartbeats.** Every worker records a heartbeat for its running trial every
``heartbeat_interval_s`` (Optuna's own heartbeat thread). A RUNNING trial is *stale*, and is
failed by the next worker that asks for a trial (Optuna's ``fail_stale_trials``) or by the
command that started the worker, when

- its last heartbeat (or its start, before the first) is older than ``grace_period_s``
  (any machine: a worker that died with its machine, or hangs), or
- its worker ran on this machine and that process is gone (its pid is dead or reused): a
  killed worker's trial is failed at once, without waiting for the grace period. The worker
  (host, pid, start time) is written as ``wb:owner`` the moment the trial starts running.

A stale trial that failed is retried once (Optuna's ``RetryHeartbeatStaleTrialCallback``: a WAITING
copy with the same parameters, which the next worker runs first; ``system_attrs`` of the copy
name the failed trial).

**Commands.** Several ``workbench tune`` commands may share a study; each promises its own
``n_trials``, and a retry replaces the failed trial *of the command that lost it*. So the owner
record also names the worker's command (:func:`command_record`: id, host, pid, start time; the
storage's ``command`` attribute, set by :mod:`workbench.learn.tune`), and

- a killed worker's trial whose command still runs on this machine is failed and queued again
  by that command's own process (it notices the death within half a second and then counts
  what the worker still owes): other processes leave it alone until the grace period. Were
  another process to fail it, the command could count the FAIL trial as finished in the moment
  before its retry was queued and restart its worker for one trial too few;
- a queued retry is taken only by a worker of the command that lost the trial while that
  command runs (on this machine: its process lives; on another machine: for ``grace_period``
  seconds after it was queued, ``wb:queued_at``); after that, any worker takes it and it counts
  as that worker's command's trial. Retries of trials without a command, and trials queued by
  hand (``enqueue_trial``), are taken by anyone.

Optuna implements heartbeats for its RDB storage (PostgreSQL, SQLite) only. For the journal
file the same interface is implemented here: a heartbeat is a trial system attribute
``wb:heartbeat`` (one journal line per beat).

**Seeds.** :class:`TrialSeededTPE` reseeds TPE's random number generators from
``(sampler_seed, trial number)`` before each trial. Trial numbers are unique in a study, so no
two trials draw the same random numbers, whichever command, worker or machine runs them, and a
given trial of a study always draws the same numbers: a single command with one worker on a
fresh study is reproducible (its TPE trials also depend on the results before them).
"""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

from optuna.samplers import TPESampler
from optuna.storages import JournalStorage, RDBStorage
from optuna.storages._heartbeat import BaseHeartbeat
from optuna.trial import TrialState

if TYPE_CHECKING:
    from workbench.learn.tune import TuneSettings

HEARTBEAT_KEY = "wb:heartbeat"
OWNER_KEY = "wb:owner"
QUEUED_KEY = "wb:queued_at"


def trial_seed(sampler_seed: int, number: int) -> int:
    """The sampler seed of trial ``number``: distinct for distinct trial numbers of one study."""
    return (int(sampler_seed) * 1_000_003 + int(number)) % (2**32)


class TrialSeededTPE(TPESampler):
    """TPE whose random streams restart from :func:`trial_seed` before each trial (see the module text)."""

    def __init__(self, sampler_seed: int = 0, **kwargs):
        super().__init__(seed=sampler_seed, **kwargs)
        self.sampler_seed = int(sampler_seed)

    def before_trial(self, study, trial) -> None:
        """Reseed from ``(sampler_seed, trial.number)``, then TPE's own preparation."""
        seed = trial_seed(self.sampler_seed, trial.number)
        self._rng.rng.seed(seed)
        self._random_sampler._rng.rng.seed(seed)
        super().before_trial(study, trial)


def _me() -> dict:
    import psutil

    return {"host": socket.gethostname(), "pid": os.getpid(), "ctime": psutil.Process().create_time()}


#: ids of the tune commands this process runs now (a process may run several in turn: the API, tests)
_RUNNING: set[str] = set()


def command_record(command_id: str) -> dict:
    """The record of a tune command this process starts running: its id, host, pid and start time."""
    _RUNNING.add(command_id)
    return {"id": command_id, **_me()}


def command_ended(record: dict) -> None:
    """The command of ``record`` (run by this process) has ended: its trials and retries are anyone's now."""
    _RUNNING.discard(record.get("id"))


def command_runs_here(command: dict) -> bool:
    """Whether the tune command of ``command`` (a :func:`command_record`) runs on this machine now."""
    if command.get("host") != socket.gethostname():
        return False
    if command.get("pid") == os.getpid():
        return command.get("id") in _RUNNING
    return not owner_is_dead(command)


#: how far two processes' readings of one process's start time (s) may differ and still name it. psutil's
#: ``create_time`` is the start since boot plus the boot time, which Linux gives as whole seconds of the wall
#: clock (``/proc/stat`` btime): when the clock is corrected, a process read later sees its owner's start a
#: second off. With the 0.01 s of before, ``make test`` (1 Dec 2026, a loaded VM) had one tune command fail
#: the other's running trial as "dead" and that command crash on telling it. A PID is reused only after the
#: kernel has gone round its whole PID space (32,768 here), not within seconds.
START_TOLERANCE_S = 2.0


def owner_is_dead(owner: Any) -> bool:
    """True when ``owner`` (host, pid, process start time) names a process of this machine that is gone."""
    import psutil

    if not isinstance(owner, dict) or owner.get("host") != socket.gethostname():
        return False
    try:
        proc = psutil.Process(int(owner["pid"]))
        return (abs(proc.create_time() - float(owner["ctime"])) > START_TOLERANCE_S
                or proc.status() == psutil.STATUS_ZOMBIE)
    except psutil.NoSuchProcess:
        return True
    except (psutil.Error, KeyError, TypeError, ValueError):
        return False


class _LocalOwner:
    """Mixin: remember which process runs a trial, and call its trial stale as soon as that process is gone."""

    _owned: set
    #: the tune command this process works for (:func:`command_record`); None outside ``workbench tune``
    command: dict | None = None

    # A trial made RUNNING and its owner are recorded together: a Ctrl-C or SIGTERM arriving in
    # between waits until the owner is written (procs.deferred_signals). Otherwise a worker stopped
    # just then leaves a RUNNING trial with no owner, stale only after the grace period.

    def create_new_trial(self, study_id: int, template_trial=None) -> int:
        from workbench import procs

        with procs.deferred_signals():
            trial_id = super().create_new_trial(study_id, template_trial)
            if template_trial is None or template_trial.state == TrialState.RUNNING:
                self._record_owner(trial_id)
        return trial_id

    def set_trial_state_values(self, trial_id: int, state, values=None) -> bool:
        if state != TrialState.RUNNING:
            return super().set_trial_state_values(trial_id, state, values)
        if self._reserved_for_another_command(trial_id):
            return False  # as if another worker had taken it: Optuna goes on to the next queued trial
        from workbench import procs

        with procs.deferred_signals():
            ok = super().set_trial_state_values(trial_id, state, values)
            if ok:  # a WAITING (e.g. retried) trial taken up here
                self._record_owner(trial_id)
        return ok

    def _record_owner(self, trial_id: int) -> None:
        if trial_id in self._owned:
            return
        self._owned.add(trial_id)
        number = self.get_trial_number_from_id(trial_id)
        self.set_trial_system_attr(trial_id, OWNER_KEY, {**_me(), "trial": number, "command": self.command})

    def _is_command(self, command: dict) -> bool:
        """Whether this process is ``command``'s own process (not one of its workers)."""
        mine = self.command
        return bool(mine) and mine.get("id") == command.get("id") and mine.get("pid") == os.getpid()

    def _left_to_its_command(self, owner: Any) -> bool:
        """A dead worker's trial is failed by its command while that command runs here (see the module text)."""
        command = owner.get("command") if isinstance(owner, dict) else None
        if not isinstance(command, dict) or self._is_command(command):
            return False
        return command_runs_here(command)

    def _reserved_for_another_command(self, trial_id: int) -> bool:
        """A queued retry of a trial of another command that still runs (see the module text)."""
        if not self.command:
            return False
        t = self.get_trial(trial_id)
        lost = t.user_attrs.get("command")
        if t.state != TrialState.WAITING or "failed_trial" not in t.system_attrs or lost in (None, self.command["id"]):
            return False
        command = (t.system_attrs.get(OWNER_KEY) or {}).get("command")
        if not isinstance(command, dict) or command.get("id") != lost:
            return False
        if command.get("host") == socket.gethostname():
            return command_runs_here(command)
        queued = t.system_attrs.get(QUEUED_KEY)
        return isinstance(queued, (int, float)) and time.time() - queued < float(self.grace_period or 0)

    def _dead_owner_ids(self, study_id: int) -> list[int]:
        out = []
        for t in self.get_all_trials(study_id, deepcopy=False, states=(TrialState.RUNNING,)):
            owner = t.system_attrs.get(OWNER_KEY)
            # a retried trial's copy carries its predecessor's owner: only this trial's own counts
            if isinstance(owner, dict) and owner.get("trial") == t.number and owner_is_dead(owner) \
                    and not self._left_to_its_command(owner):
                out.append(t._trial_id)
        return out


class HeartbeatJournalStorage(_LocalOwner, JournalStorage, BaseHeartbeat):
    """A journal-file storage with heartbeats (see the module text)."""

    def __init__(self, backend, *, heartbeat_interval: int, grace_period: int,
                 stale_trial_callback: Callable | None = None):
        super().__init__(backend)
        self.heartbeat_interval = int(heartbeat_interval)
        self.grace_period = int(grace_period)
        self._stale_cb = stale_trial_callback
        self._owned = set()

    def record_heartbeat(self, trial_id: int) -> None:
        """A heartbeat: this process and the time, as a trial system attribute."""
        number = self.get_trial_number_from_id(trial_id)
        self.set_trial_system_attr(trial_id, HEARTBEAT_KEY, {**_me(), "trial": number, "t": time.time()})

    def _get_stale_trial_ids(self, study_id: int) -> list[int]:
        now = time.time()
        stale = []
        dead = set(self._dead_owner_ids(study_id))
        for t in self.get_all_trials(study_id, deepcopy=False, states=(TrialState.RUNNING,)):
            beat = t.system_attrs.get(HEARTBEAT_KEY)
            if t._trial_id in dead:
                stale.append(t._trial_id)
            elif isinstance(beat, dict) and beat.get("trial") == t.number:
                gone = owner_is_dead(beat) and not self._left_to_its_command(t.system_attrs.get(OWNER_KEY))
                if gone or now - float(beat["t"]) > self.grace_period:
                    stale.append(t._trial_id)
            elif t.datetime_start is not None:
                start = t.datetime_start.timestamp()
                if now - start > self.grace_period:
                    stale.append(t._trial_id)
        return stale

    def get_heartbeat_interval(self) -> int | None:
        """Seconds between heartbeats."""
        return self.heartbeat_interval

    def get_heartbeat_stale_trial_callback(self):
        """What runs for each stale trial failed (the retry)."""
        return self._stale_cb

    def get_failed_trial_callback(self):
        """Older name of :meth:`get_heartbeat_stale_trial_callback`."""
        return self._stale_cb


class HeartbeatRDBStorage(_LocalOwner, RDBStorage):
    """Optuna's RDB storage (heartbeats in its own table), plus the same-machine dead-worker check."""

    def __init__(self, url: str, **kwargs):
        super().__init__(url, **kwargs)
        self._owned = set()

    def record_heartbeat(self, trial_id: int) -> None:
        """Optuna's heartbeat, and this process as the trial's owner (once)."""
        super().record_heartbeat(trial_id)
        self._record_owner(trial_id)

    def _get_stale_trial_ids(self, study_id: int) -> list[int]:
        ids = super()._get_stale_trial_ids(study_id)
        return ids + [i for i in self._dead_owner_ids(study_id) if i not in ids]


def retry_callback(max_retry: int):
    """Optuna's retry of failed stale trials (``max_retry`` copies at most), the copy stamped ``wb:queued_at``."""
    import warnings

    import optuna

    class QueuedRetry(optuna.storages.RetryHeartbeatStaleTrialCallback):
        def __call__(self, study, trial) -> None:
            trial.system_attrs = {**trial.system_attrs, QUEUED_KEY: time.time()}
            super().__call__(study, trial)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        return QueuedRetry(max_retry=max_retry)


def retried_numbers(trials) -> set[int]:
    """Numbers of failed trials that have a retry copy in ``trials``."""
    out: set[int] = set()
    for t in trials:
        for n in t.system_attrs.get("retry_history", []) or []:
            out.add(int(n))
    return out


def resolve_storage(storage: str | None, study: str, tune: "TuneSettings | None" = None):
    """An Optuna storage with heartbeats: default journal file, a ``*.journal`` path, or an Optuna storage URL.

    Returns ``(storage, where)``; heartbeat interval, grace period and retries from ``tune``.
    """
    from optuna.storages.journal import JournalFileBackend, JournalFileOpenLock

    from workbench.errors import ContractError
    from workbench.learn.tune import TuneSettings
    from workbench.project import project_root

    tune = tune or TuneSettings()
    beat = {"heartbeat_interval": max(1, int(tune.heartbeat_interval_s)),
            "grace_period": max(int(tune.grace_period_s), 2 * int(tune.heartbeat_interval_s))}

    if storage is None or storage.endswith(".journal") or storage.startswith("journal:"):
        path = Path(storage.removeprefix("journal:") if storage else project_root() / ".optuna" / f"{study}.journal")
        path.parent.mkdir(parents=True, exist_ok=True)
        # open()-based lock: works on local disks and NFS alike, no symlink permissions needed
        return HeartbeatJournalStorage(JournalFileBackend(str(path), lock_obj=JournalFileOpenLock(str(path))), **beat,
                                       stale_trial_callback=retry_callback(tune.max_retry)), str(path)
    if "://" not in storage:
        raise ContractError(f"storage {storage!r} is neither a .journal file nor a storage URL",
                            hint="e.g. .optuna/study.journal or postgresql://user@host/db")
    # Several machines starting on an empty database race to create Optuna's schema (PostgreSQL
    # then raises a unique violation on its enum types): whoever loses waits and retries once the
    # winner's tables exist.
    from sqlalchemy.exc import IntegrityError, ProgrammingError

    from workbench.tracking import retry_race

    return retry_race(lambda: HeartbeatRDBStorage(storage, **beat,
                                                  heartbeat_stale_trial_callback=retry_callback(tune.max_retry)),
                      (IntegrityError, ProgrammingError)), storage


def fail_stale(study) -> list[int]:
    """Fail the study's stale RUNNING trials now (dead workers of this machine, or silent past the grace period)."""
    import warnings

    import optuna

    before = {t.number for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        optuna.storages.fail_stale_trials(study)
    after = {t.number for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))}
    return sorted(before - after)
