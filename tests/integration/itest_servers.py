"""Real servers for integration tests: a throwaway PostgreSQL cluster and an MLflow server, both on loopback."""

from __future__ import annotations

import os
import pwd
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from contextlib import contextmanager
from pathlib import Path

PG_BIN_CANDIDATES = ("/usr/lib/postgresql/15/bin", "/usr/lib/postgresql/16/bin", "/usr/lib/postgresql/17/bin")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def pg_bin() -> Path | None:
    for cand in PG_BIN_CANDIDATES:
        if Path(cand, "initdb").exists():
            return Path(cand)
    found = shutil.which("initdb")
    return Path(found).parent if found else None


def _as_postgres(cmd: list[str]) -> list[str]:
    """PostgreSQL refuses to run as root: run it as the 'postgres' user then."""
    if os.geteuid() == 0:
        return ["runuser", "-u", "postgres", "--", *cmd]
    return cmd


@contextmanager
def postgres_server(workdir: Path):
    """Start a fresh PostgreSQL cluster on a free loopback port; yield its base URL (no database)."""
    bindir = pg_bin()
    if bindir is None:
        raise RuntimeError("PostgreSQL server binaries not found (apt-get install postgresql)")
    # the server runs as 'postgres', which cannot enter pytest's root-only temp folders: use /tmp
    import tempfile

    own = Path(tempfile.mkdtemp(prefix="wb-pg-"))
    data = own / "pgdata"
    sock = own / "pgsock"
    data.mkdir()
    sock.mkdir()
    workdir = own
    if os.geteuid() == 0:
        pw = pwd.getpwnam("postgres")
        for p in (workdir, data, sock):
            os.chown(p, pw.pw_uid, pw.pw_gid)
        os.chmod(workdir, 0o755)
    subprocess.run(_as_postgres([str(bindir / "initdb"), "-D", str(data), "-U", "wb", "--auth=trust",
                                 "-E", "UTF8"]), check=True, capture_output=True)
    port = free_port()
    log = workdir / "pg.log"
    subprocess.run(_as_postgres([str(bindir / "pg_ctl"), "-D", str(data), "-l", str(log), "-w", "-o",
                                 f"-p {port} -k {sock} -c listen_addresses=127.0.0.1 -c max_connections=100",
                                 "start"]), check=True, capture_output=True)
    try:
        yield f"postgresql+psycopg2://wb@127.0.0.1:{port}"
    finally:
        subprocess.run(_as_postgres([str(bindir / "pg_ctl"), "-D", str(data), "-m", "fast", "-w", "stop"]),
                       capture_output=True)
        shutil.rmtree(own, ignore_errors=True)


def create_database(base_url: str, name: str) -> str:
    import psycopg2

    conn = psycopg2.connect(base_url.replace("+psycopg2", "") + "/postgres")
    conn.autocommit = True
    with conn.cursor() as cur:
        cur.execute(f'CREATE DATABASE "{name}"')
    conn.close()
    return f"{base_url}/{name}"


@contextmanager
def mlflow_server(backend_uri: str, artifacts_dir: Path, timeout_s: float = 120.0):
    """Start ``mlflow server`` on a free loopback port (artifacts served by it); yield its URL."""
    port = free_port()
    artifacts_dir.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", backend_uri,
           "--artifacts-destination", artifacts_dir.as_uri(), "--serve-artifacts",
           "--host", "127.0.0.1", "--port", str(port), "--workers", "1"]
    log = open(artifacts_dir.parent / f"mlflow-server-{port}.log", "wb")
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            if proc.poll() is not None:
                raise RuntimeError(f"mlflow server exited: {(artifacts_dir.parent / f'mlflow-server-{port}.log').read_text()[-2000:]}")
            try:
                with urllib.request.urlopen(url + "/health", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("mlflow server did not answer in time")
            time.sleep(0.5)
        yield url
    finally:
        import signal

        try:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=20)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            os.killpg(proc.pid, signal.SIGKILL)
        log.close()
