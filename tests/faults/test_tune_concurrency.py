"""Concurrent tune commands on one study: distinct seeds, progress per command, a killed worker's trial
failed and retried, every trial accounted for, none left RUNNING (journal file and PostgreSQL)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import textwrap
import time

import pytest
from proctree import PROJECT, Verb, project_env, small_parquet, tiny_learn_config

pytestmark = pytest.mark.faults

# ----------------------------------------------------------------------------- fast: the storage itself


def _journal(path):
    from workbench.learn.tune import TuneSettings
    from workbench.learn.tune_storage import resolve_storage

    # a 10 s interval: the worker below is killed between beats, not while it holds the journal's lock
    # (a lock left by a killed writer blocks the journal for Optuna's 30 s lock grace period)
    return resolve_storage(str(path), "s", TuneSettings(heartbeat_interval_s=10, grace_period_s=30))[0]


def test_a_trial_whose_worker_was_killed_is_failed_at_once_and_queued_again(tmp_path):
    import optuna

    journal = tmp_path / "s.journal"
    optuna.create_study(study_name="s", storage=_journal(journal))
    # a real worker process: asks for a trial, beats, then hangs until it is killed
    code = textwrap.dedent(f"""
        import time, optuna
        from workbench.learn.tune import TuneSettings
        from workbench.learn.tune_storage import resolve_storage
        from optuna.storages._heartbeat import get_heartbeat_thread
        st = resolve_storage({str(journal)!r}, "s", TuneSettings(heartbeat_interval_s=10, grace_period_s=30))[0]
        study = optuna.load_study(study_name="s", storage=st)
        t = study.ask({{"x": optuna.distributions.FloatDistribution(0, 1)}})
        with get_heartbeat_thread(t._trial_id, st):
            while "wb:heartbeat" not in st.get_trial(t._trial_id).system_attrs:
                time.sleep(0.05)
            print("running", flush=True)
            time.sleep(600)
    """)  # it prints once its first heartbeat is written; the next is 10 s later
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": str(PROJECT)})
    try:
        assert proc.stdout.readline().strip() == "running"
        study = optuna.load_study(study_name="s", storage=_journal(journal))
        optuna.storages.fail_stale_trials(study)  # the worker lives: its trial is not stale
        assert [t.state.name for t in study.get_trials()] == ["RUNNING"]
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    optuna.storages.fail_stale_trials(study)  # well inside the 30 s grace period: the dead pid tells
    trials = study.get_trials()
    assert [t.state.name for t in trials] == ["FAIL", "WAITING"]
    assert trials[1].params == trials[0].params and trials[1].system_attrs["failed_trial"] == 0


def _signal_while_recording_the_owner(storage, monkeypatch):
    """SIGTERM to this process just before the trial's owner is written (the worst moment to be stopped)."""
    from workbench.learn.tune_storage import OWNER_KEY

    real = type(storage).set_trial_system_attr
    sent = []

    def set_attr(self, trial_id, key, value):
        if key == OWNER_KEY and not sent:
            sent.append(trial_id)
            os.kill(os.getpid(), signal.SIGTERM)  # Python runs its handler at the next bytecode
        return real(self, trial_id, key, value)

    monkeypatch.setattr(type(storage), "set_trial_system_attr", set_attr)
    return sent


def _raise_on_sigterm():
    def on_term(signum, frame):
        raise KeyboardInterrupt("SIGTERM")

    return signal.signal(signal.SIGTERM, on_term)


def test_a_worker_stopped_as_it_starts_a_trial_records_the_trials_owner_first(tmp_path, monkeypatch):
    """The CI failure of 2026-11-25: a worker stopped between creating its trial and writing the trial's owner
    left a RUNNING trial that no one could call stale before the grace period. The stop now waits for the owner."""
    import optuna

    from workbench.learn.tune_storage import OWNER_KEY, fail_stale

    storage = _journal(tmp_path / "s.journal")
    study = optuna.create_study(study_name="s", storage=storage)
    old = _raise_on_sigterm()
    try:
        sent = _signal_while_recording_the_owner(storage, monkeypatch)
        with pytest.raises(KeyboardInterrupt):
            study.ask()
    finally:
        signal.signal(signal.SIGTERM, old)
    assert sent, "the signal was never sent: the owner was not recorded through set_trial_system_attr"
    (trial,) = study.get_trials()
    assert trial.state.name == "RUNNING"
    owner = trial.system_attrs.get(OWNER_KEY)
    assert owner and owner["pid"] == os.getpid() and owner["trial"] == trial.number
    # the same for a queued (retried) trial taken up: set RUNNING and its owner written together
    study.enqueue_trial({})
    old = _raise_on_sigterm()
    try:
        sent.clear()
        with pytest.raises(KeyboardInterrupt):
            study.ask()
    finally:
        signal.signal(signal.SIGTERM, old)
    taken = study.get_trials()[-1]
    assert taken.state.name == "RUNNING" and taken.system_attrs[OWNER_KEY]["trial"] == taken.number
    assert fail_stale(study) == []  # this process lives: neither trial is stale


def _storage(tmp_path, kind: str):
    """A journal file or an RDB (SQLite standing in for PostgreSQL: the same storage class) of study "s"."""
    from workbench.learn.tune import TuneSettings
    from workbench.learn.tune_storage import resolve_storage

    if kind == "journal":
        return _journal(tmp_path / "s.journal")
    return resolve_storage(f"sqlite:///{tmp_path / 's.db'}", "s", TuneSettings(heartbeat_interval_s=10,
                                                                          grace_period_s=30))[0]


def _a_killed_workers_trial(storage, study, command: dict, worker: int) -> int:
    """A RUNNING trial of ``command``'s ``worker`` whose process is gone (SIGKILLed mid-trial); returns its number."""
    import optuna

    from workbench.learn.tune_storage import OWNER_KEY

    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # its pid names no process now (and were it reused, the start time 0 would not match)
    t = study.ask({"x": optuna.distributions.FloatDistribution(0, 1)})
    t.set_user_attr("command", command["id"])
    t.set_user_attr("worker", worker)
    storage.set_trial_system_attr(t._trial_id, OWNER_KEY, {"host": command["host"], "pid": gone.pid, "ctime": 0.0,
                                                           "trial": t.number, "command": command})
    return t.number


@pytest.mark.parametrize("kind", ["journal", "rdb"])
def test_a_killed_workers_trial_is_queued_again_before_its_command_counts_what_the_worker_owes(tmp_path, monkeypatch,
                                                                                             kind):
    """The fresh-clone failure of 2026-11-25 ({A: 3, B: 2} trials): a worker of command B failed A's killed trial and,
    before B had queued its retry, A counted what its killed worker still owed. A FAIL trial with no retry yet counts
    as finished, so A restarted the worker for one trial too few and ran 2 of its 3. This test plays B and A in that
    order, in one process: B fails the trial, and A's count runs between B's FAIL and B's retry."""
    import optuna

    from workbench.learn.tune_storage import command_ended, command_record, fail_stale
    from workbench.learn.tune_workers import _after_kill

    a_store = _storage(tmp_path, kind)
    study_a = optuna.create_study(study_name="s", storage=a_store)
    b_store = _storage(tmp_path, kind)
    study_b = optuna.load_study(study_name="s", storage=b_store)
    command_a = command_record("A")  # this process plays command A, running
    a_store.command = command_a  # A's own storage: the command's process
    b_store.command = {**command_a, "id": "B", "pid": 1}  # a worker of command B (another process)
    done = study_a.ask({"x": optuna.distributions.FloatDistribution(0, 1)})  # worker 0's first trial, complete
    done.set_user_attr("command", "A")
    done.set_user_attr("worker", 0)
    study_a.tell(done, 1.0)
    killed = _a_killed_workers_trial(a_store, study_a, command_a, worker=0)

    said, owed = [], []
    real = b_store.get_heartbeat_stale_trial_callback()

    def between_fail_and_retry(study, trial):  # B has failed the trial; A notices its worker's death now
        owed.append(_after_kill(study_a, {"command": "A"}, 0, 2, -signal.SIGKILL, said.append))
        real(study, trial)

    monkeypatch.setattr(b_store, "get_heartbeat_stale_trial_callback", lambda: between_fail_and_retry)
    try:
        fail_stale(study_b)  # B's worker, as it starts its next trial (Optuna's optimize loop)
        if not owed:  # B left the trial to its own command: A notices the death at its next look
            owed.append(_after_kill(study_a, {"command": "A"}, 0, 2, -signal.SIGKILL, said.append))
    finally:
        command_ended(command_a)
    trials = study_a.get_trials()
    retries = [t for t in trials if t.system_attrs.get("failed_trial") == killed]
    assert [t.state.name for t in trials if t.number == killed] == ["FAIL"]
    assert len(retries) == 1 and retries[0].state.name == "WAITING", [(t.number, t.state.name) for t in trials]
    # worker 0 owed 2 trials: one is COMPLETE, the killed one is replaced by its retry: 1 still owed
    assert owed == [1], (owed, said)
    assert said == [f"worker 0 was killed (SIGKILL); trial(s) [{killed}] failed and queued again"]


@pytest.mark.parametrize("kind", ["journal", "rdb"])
def test_a_queued_retry_is_run_by_the_command_that_lost_the_trial_while_that_command_runs(tmp_path, kind):
    """Each command runs its own --n-trials; a retry replaces the failed trial of the command that lost it.
    Another command's worker takes the retry only once that command has ended (on another machine: once the
    retry has waited a grace period), and trials queued by hand are anyone's."""
    import optuna

    from workbench.learn.tune_storage import OWNER_KEY, QUEUED_KEY, command_ended, command_record, fail_stale

    a_store = _storage(tmp_path, kind)
    study_a = optuna.create_study(study_name="s", storage=a_store)
    a_worker, b_worker = _storage(tmp_path, kind), _storage(tmp_path, kind)
    command_a = command_record("A")
    a_store.command = a_worker.command = command_a  # A's process; one of its workers
    b_worker.command = {**command_a, "id": "B", "pid": 1}
    space = {"x": optuna.distributions.FloatDistribution(0, 1)}

    def ask(storage):
        return optuna.load_study(study_name="s", storage=storage).ask(space).number

    def queued():
        return [t.number for t in study_a.get_trials() if t.state.name == "WAITING"]

    try:
        killed = _a_killed_workers_trial(a_store, study_a, command_a, worker=0)
        assert fail_stale(study_a) == [killed]  # A, noticing its worker's death
        (retry,) = queued()
        assert ask(b_worker) != retry and queued() == [retry]  # B makes a fresh trial, leaves A's retry
        assert ask(a_worker) == retry  # A's worker takes it
        killed = _a_killed_workers_trial(a_store, study_a, command_a, worker=1)
        assert fail_stale(study_a) == [killed]
        (retry,) = queued()
    finally:
        command_ended(command_a)
    assert ask(b_worker) == retry  # A has ended: its retry is anyone's
    # a retry of a command on another machine: its own for the grace period (30 s) after it was queued
    elsewhere = {"id": "C", "host": "elsewhere", "pid": 1, "ctime": 0.0}
    study_a.add_trial(optuna.trial.create_trial(
        state=optuna.trial.TrialState.WAITING, params={"x": 0.5}, distributions=space, user_attrs={"command": "C"},
        system_attrs={"failed_trial": 0, OWNER_KEY: {**elsewhere, "trial": 0, "command": elsewhere},
                      QUEUED_KEY: time.time() - 5}))
    (retry,) = queued()
    assert ask(b_worker) != retry and queued() == [retry]
    a_store.set_trial_system_attr(study_a.get_trials()[retry]._trial_id, QUEUED_KEY, time.time() - 40)
    assert ask(b_worker) == retry
    study_a.enqueue_trial({"x": 0.25}, user_attrs={"command": "A"})  # queued by hand, not a retry: anyone's
    (hand,) = queued()
    assert ask(b_worker) == hand


def test_a_trial_silent_past_the_grace_period_is_failed(tmp_path):
    import optuna

    from workbench.learn.tune_storage import HEARTBEAT_KEY

    storage = _journal(tmp_path / "s.journal")
    study = optuna.create_study(study_name="s", storage=storage)
    t = study.ask()
    # its last heartbeat came from another machine 40 s ago (grace period 30 s)
    storage.set_trial_system_attr(t._trial_id, HEARTBEAT_KEY, {"host": "elsewhere", "pid": 1, "ctime": 0.0,
                                                               "trial": t.number, "t": time.time() - 40})
    t2 = study.ask()
    storage.set_trial_system_attr(t2._trial_id, HEARTBEAT_KEY, {"host": "elsewhere", "pid": 1, "ctime": 0.0,
                                                                "trial": t2.number, "t": time.time() - 5})
    optuna.storages.fail_stale_trials(study)
    states = {x.number: x.state.name for x in study.get_trials()}
    assert states[t.number] == "FAIL" and states[t2.number] == "RUNNING"


def test_trials_draw_distinct_seeds_whichever_worker_runs_them_and_the_same_seed_for_the_same_trial(tmp_path):
    import optuna

    from workbench.learn.tune_storage import TrialSeededTPE

    space = {"lr": optuna.distributions.FloatDistribution(1e-4, 1e-1, log=True),
             "h": optuna.distributions.IntDistribution(8, 256)}

    def draws(study_name):
        study = optuna.create_study(study_name=study_name, storage=_journal(tmp_path / f"{study_name}.journal"))
        # two "workers" (samplers built alike, as two commands would) take turns on one study
        a, b = TrialSeededTPE(0, constant_liar=True), TrialSeededTPE(0, constant_liar=True)
        out = []
        for i in range(6):
            study.sampler = a if i % 2 == 0 else b
            t = study.ask(space)
            out.append((t.number, t.params["lr"], t.params["h"]))
            study.tell(t, (t.params["lr"] - 0.01) ** 2)
        return out

    first, again = draws("one"), draws("two")
    assert len({(lr, h) for _, lr, h in first}) == 6  # no trial repeats another's draw
    assert first == again  # a study's trial k always draws the same numbers: reproducible


# ----------------------------------------------------------------------------- slow: two real commands


_STORAGES: dict = {}


def _trials(storage_arg: str, study: str):
    import optuna

    from workbench.learn.tune_storage import resolve_storage

    if storage_arg not in _STORAGES:  # one storage (one connection pool) per URL
        _STORAGES[storage_arg] = resolve_storage(storage_arg, study)[0]
    return optuna.load_study(study_name=study, storage=_STORAGES[storage_arg]).get_trials()


def _a_running_trial_of(a, b, storage_arg: str, killed: dict) -> bool:
    """Whether one of command A's workers is training a trial (its 7 parameters drawn); if so, note it in `killed`."""
    from workbench.learn.tune_storage import HEARTBEAT_KEY, OWNER_KEY

    pids = {k.pid for k in a.watch() if "workbench.learn.tune" in " ".join(k.cmdline())}
    b.watch()
    try:
        trials = _trials(storage_arg, "c")
    except Exception:  # noqa: BLE001 - the study may not exist yet
        return False
    for t in trials:
        if t.state.name != "RUNNING" or "command" not in t.user_attrs or len(t.params) < 7:
            continue
        who = t.system_attrs.get(HEARTBEAT_KEY) or t.system_attrs.get(OWNER_KEY) or {}
        if who.get("pid") in pids and who.get("trial") == t.number:
            killed.update(pid=who["pid"], trial=t.number)
            return True
    return False


def _two_commands_one_killed_worker(tmp_path, storage_arg: str):
    data = small_parquet(tmp_path)
    cfg = tiny_learn_config(tmp_path, max_epochs=6, pruner={"type": "none"}, heartbeat_interval_s=2,
                            grace_period_s=60)
    env = project_env(tmp_path)
    args = ["tune", "--config", str(cfg), "--data", str(data), "--study", "c", "--storage", storage_arg,
            "--n-trials", "3", "--workers", "2", "--no-mlflow"]
    a = Verb(args, env, tmp_path, tmp_path / "a.log")
    b = Verb(args, env, tmp_path, tmp_path / "b.log")
    killed = {}
    try:
        def victim():
            return _a_running_trial_of(a, b, storage_arg, killed)

        a.wait_for(victim, 400, "a running trial of command A's worker")
        os.kill(killed["pid"], signal.SIGKILL)
        for v in (a, b):
            deadline = time.monotonic() + 600
            while v.proc.poll() is None and time.monotonic() < deadline:
                v.watch()
                time.sleep(0.5)
        assert a.proc.returncode == 0, a.text()[-3000:]
        assert b.proc.returncode == 0, b.text()[-3000:]
        assert a.survivors(20) == [] and b.survivors(20) == []
    finally:
        a.cleanup()
        b.cleanup()
    trials = _trials(storage_arg, "c")
    states = {t.number: t.state.name for t in trials}
    # every trial accounted for: none RUNNING or WAITING, the killed one FAIL with a retry that ran
    assert not [n for n, s in states.items() if s in ("RUNNING", "WAITING")], states
    assert states[killed["trial"]] == "FAIL"
    retries = [t for t in trials if t.system_attrs.get("failed_trial") == killed["trial"]]
    assert len(retries) == 1 and retries[0].state.name in ("COMPLETE", "PRUNED")
    lost = next(t for t in trials if t.number == killed["trial"])
    assert retries[0].params == lost.params
    # the retry replaced the failed trial of the command that lost it (A), which was still running
    assert retries[0].user_attrs["command"] == lost.user_attrs["command"], (lost.user_attrs, retries[0].user_attrs)
    # each command ran exactly its 3 trials (a failed trial counted by its retry)
    commands = {}
    for t in trials:
        if t.number != killed["trial"]:
            commands.setdefault(t.user_attrs["command"], []).append(t.number)
    assert sorted(len(v) for v in commands.values()) == [3, 3], commands
    # distinct seeds, and no two first-hand trials drew the same parameters
    seeds = [t.user_attrs["sampler_seed"] for t in trials]
    assert len(set(seeds)) == len(seeds)
    fresh = [t for t in trials if "failed_trial" not in t.system_attrs]
    assert len({tuple(sorted(t.params.items())) for t in fresh}) == len(fresh)
    # progress counted per command: "trial k/3", never more than 3, up to 3
    for v in (a, b):
        counts = [int(k) for k, n in re.findall(r"trial (\d+)/(\d+)", v.text()) if n == "3"]
        assert counts and max(counts) == 3, v.text()[-2000:]
    assert "worker" in a.text() and "was killed (SIGKILL)" in a.text()
    return trials


@pytest.mark.slow
def test_two_commands_two_workers_on_a_journal_one_worker_killed(tmp_path):
    _two_commands_one_killed_worker(tmp_path, str(tmp_path / "c.journal"))


@pytest.mark.slow
def test_two_commands_two_workers_on_postgresql_one_worker_killed(tmp_path):
    sys.path.insert(0, str(PROJECT / "tests" / "integration"))
    try:
        from itest_servers import create_database, pg_bin, postgres_server
    finally:
        sys.path.pop(0)
    if pg_bin() is None:
        pytest.skip("PostgreSQL server binaries not installed (make system-deps)")
    with postgres_server(tmp_path) as base:
        url = create_database(base, "optuna")
        _two_commands_one_killed_worker(tmp_path, url)
