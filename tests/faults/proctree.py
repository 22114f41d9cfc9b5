"""Helpers of the process-tree fault tests: start a verb, watch its descendants, kill it, find survivors."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import psutil

PROJECT = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def port_open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(1.0)
        return s.connect_ex(("127.0.0.1", port)) == 0


def project_env(root: Path, **extra) -> dict:
    """An isolated project (WORKBENCH_HOME) with its own temp folder and MLflow store."""
    (root / "pyproject.toml").touch()
    tmp = root / "tmpdir"
    tmp.mkdir(exist_ok=True)
    env = {**os.environ, "WORKBENCH_HOME": str(root), "TMPDIR": str(tmp), "MPLBACKEND": "Agg",
           "OPENBLAS_NUM_THREADS": "1", "MLFLOW_TRACKING_URI": f"sqlite:///{root / 'mlflow.db'}",
           "PYTHONPATH": str(PROJECT)}
    env.pop("DVC_STAGE", None)
    env.update(extra)
    return env


def _default_sigint() -> None:
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


class Verb:
    """A ``workbench`` command run as a subprocess (own session, so the test's signals go to it alone)."""

    def __init__(self, args: list[str], env: dict, cwd: Path, log: Path):
        self.log_path = log
        self._log = open(log, "wb")
        # SIGINT at its default in the command, as in a terminal: a test run started in the background
        # (make test under nohup, CI runners) hands an ignored SIGINT down, which the command would keep
        self.proc = subprocess.Popen([sys.executable, "-m", "workbench.cli", *args], stdout=self._log,
                                     stderr=subprocess.STDOUT, env=env, cwd=cwd, start_new_session=True,
                                     preexec_fn=_default_sigint)
        self.seen: dict[int, tuple[float, str]] = {}

    def text(self) -> str:
        return self.log_path.read_text(errors="replace")

    def watch(self) -> list[psutil.Process]:
        """Record the current descendants (pid, start time, command line); returns them."""
        try:
            kids = psutil.Process(self.proc.pid).children(recursive=True)
        except psutil.NoSuchProcess:
            return []
        for k in kids:
            # always the latest command line: a child caught between fork and exec still shows its
            # parent's (procs.popen runs a preexec function there), and would never be told apart
            try:
                self.seen[k.pid] = (k.create_time(), " ".join(k.cmdline())[:160])
            except psutil.Error:
                pass
        return kids

    def wait_for(self, pred, timeout_s: float, what: str):
        """Poll ``pred()`` (watching descendants meanwhile) until true; fail with the log otherwise."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.watch()
            if pred():
                self.watch()
                return
            if self.proc.poll() is not None:
                raise AssertionError(f"command ended ({self.proc.returncode}) before {what}:\n{self.text()[-3000:]}")
            time.sleep(0.2)
        raise AssertionError(f"timed out waiting for {what}:\n{self.text()[-3000:]}")

    def kill(self, sig: int, wait_s: float = 60.0) -> int | None:
        """Send ``sig`` to the command's own pid (not its group) and wait for it to end."""
        self.watch()
        os.kill(self.proc.pid, sig)
        try:
            return self.proc.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            return None

    def survivors(self, timeout_s: float = 30.0) -> list[str]:
        """Recorded descendants still alive after ``timeout_s`` (same pid and start time)."""
        deadline = time.monotonic() + timeout_s
        while True:
            alive = []
            for pid, (ctime, cmd) in self.seen.items():
                try:
                    p = psutil.Process(pid)
                    if abs(p.create_time() - ctime) < 0.01 and p.status() != psutil.STATUS_ZOMBIE:
                        alive.append(f"{pid} {cmd}")
                except psutil.NoSuchProcess:
                    pass
            if not alive or time.monotonic() > deadline:
                return alive
            time.sleep(0.5)

    def cleanup(self) -> None:
        """Kill whatever is left (so a failing test leaves nothing behind either)."""
        for pid, (ctime, _) in self.seen.items():
            try:
                p = psutil.Process(pid)
                if abs(p.create_time() - ctime) < 0.01:
                    p.kill()
            except psutil.Error:
                pass
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
            self.proc.wait()
        self._log.close()


def small_parquet(folder: Path) -> Path:
    """A small processed-format tunnel table (the learn tests' synthetic campaign)."""
    sys.path.insert(0, str(PROJECT / "tests" / "learn"))
    try:
        from learn_helpers import make_frame
    finally:
        sys.path.pop(0)
    out = folder / "synth.parquet"
    if not out.exists():
        make_frame(interpolated_speeds=(0.15,)).write_parquet(out)
    return out


def tiny_learn_config(folder: Path, **tune) -> Path:
    """pipelines/learn.yaml shrunk: small nets, few windows, long enough trials to be caught running."""
    import yaml

    doc = yaml.safe_load((PROJECT / "pipelines" / "learn.yaml").read_text())
    doc["train"]["data"].update(train_windows_per_epoch=512, batch_size=128)
    doc["train"]["trainer"].update(max_time_s=None, early_stop_patience=0, torch_threads=1)
    doc["tune"].update({"max_epochs": 2, "train_windows_per_epoch": 512, **tune})
    doc["tune"]["space"]["hidden_size"] = {"type": "categorical", "choices": [8, 16]}
    doc["tune"]["space"]["num_layers"] = {"type": "int", "low": 1, "high": 1}
    doc["tune"]["space"]["variant"] = {"type": "categorical", "choices": ["lstm", "gru"]}
    path = folder / "learn.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path
