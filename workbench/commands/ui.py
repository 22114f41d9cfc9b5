"""``workbench ui``: the MLflow UI over the project's tracking store, on loopback by default."""

from __future__ import annotations

from workbench.commands._help import add_verb


def register(sub) -> None:
    """Add the ``ui`` verb."""
    p = add_verb(
        sub, "ui", help="open the MLflow UI over the project's runs and models",
        description="Start the MLflow UI on this machine over the project's tracking store "
        "(mlflow.db and mlartifacts/ at the project root, or --tracking-uri). It listens on the "
        "loopback interface only unless --host says otherwise. The URL is printed once the page "
        "answers (the server takes 20-60 s to start; a line shows the wait). Stop it with Ctrl-C or "
        "SIGTERM: the server, its job runner and its workers all stop and the port is freed, also "
        "when this command is killed.",
        examples="""\
  workbench ui                         # http://127.0.0.1:5000, the project's own store
  workbench ui --port 5055             # another port
  workbench ui --host 0.0.0.0          # reachable from other machines (think twice)
  workbench ui --tracking-uri postgresql://mlflow@db/mlflow --artifacts s3://bucket/mlflow
""")
    p.add_argument("--host", default="127.0.0.1", help="interface to listen on (default: loopback only)")
    p.add_argument("--port", type=int, default=5000, help="port (default 5000)")
    p.add_argument("--tracking-uri", default=None,
                   help="backend store (default: the project's sqlite store, or MLFLOW_TRACKING_URI)")
    p.add_argument("--artifacts", default=None, help="artifact root (default: the project's mlartifacts/)")
    p.add_argument("--wait-s", type=float, default=300.0,
                   help="how long to wait for the page to answer before giving up (default 300 s)")
    p.set_defaults(func=run)


def server_command(host: str, port: int, tracking_uri: str | None = None, artifacts: str | None = None) -> list[str]:
    """The ``mlflow server`` command line the UI runs (also used by tests and the scale-out docs)."""
    import sys

    from workbench.project import mlflow_artifact_root, mlflow_tracking_uri

    uri = mlflow_tracking_uri(tracking_uri)
    cmd = [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", uri,
           "--host", host, "--port", str(port), "--workers", "1"]
    if uri.startswith("sqlite:") or artifacts:
        cmd += ["--default-artifact-root", artifacts or mlflow_artifact_root()]
    if host not in ("127.0.0.1", "localhost", "::1"):
        cmd += ["--allowed-hosts", "*"]
    return cmd


def _probe_host(host: str) -> str:
    """Where this machine reaches a server listening on ``host`` (a wildcard address: loopback)."""
    return {"0.0.0.0": "127.0.0.1", "::": "::1", "": "127.0.0.1"}.get(host, host)


def port_in_use(host: str, port: int) -> bool:
    """True when something already listens on ``host:port``."""
    import socket

    probe = _probe_host(host)
    fam = socket.AF_INET6 if ":" in probe else socket.AF_INET
    with socket.socket(fam, socket.SOCK_STREAM) as s:
        s.settimeout(1.0)
        return s.connect_ex((probe, port)) == 0


def wait_until_answering(url: str, proc, timeout_s: float, report=None, every_s: float = 5.0) -> float:
    """Poll ``url`` until it answers HTTP 200; a progress line every ``every_s``; returns the seconds waited.

    Raises :class:`~workbench.errors.StageError` when the server exits first or ``timeout_s`` passes.
    """
    import time
    import urllib.error
    import urllib.request

    from workbench.errors import StageError

    t0 = last = time.monotonic()
    while True:
        if proc.poll() is not None:
            raise StageError(f"the MLflow server exited with status {proc.returncode} before answering",
                             hint="see its messages above (a port in use, a bad --tracking-uri?)")
        try:
            with urllib.request.urlopen(url, timeout=2) as r:
                if r.status == 200:
                    return time.monotonic() - t0
        except (OSError, urllib.error.URLError):
            pass
        now = time.monotonic()
        if now - t0 > timeout_s:
            raise StageError(f"the MLflow server did not answer {url} within {timeout_s:.0f} s",
                             hint="a loaded machine starts it slowly: try --wait-s 600")
        if report and now - last >= every_s:
            report(f"starting the MLflow server... {now - t0:.0f} s (it takes 20-60 s)")
            last = now
        time.sleep(0.5)


def run(args) -> int:
    """Start the server under a guard, wait until its page answers, print the URL, run until stopped.

    Ctrl-C, SIGTERM or SIGHUP (and the death of this process, even by SIGKILL) end the MLflow
    server with its web server, job runner and workers, and free the port.
    """
    from workbench import procs
    from workbench.console import info
    from workbench.errors import ContractError

    procs.install()
    if port_in_use(args.host, args.port):
        raise ContractError(f"port {args.port} on {args.host} is already in use (another workbench ui?)",
                            hint="stop that one, or choose another with --port")
    cmd = server_command(args.host, args.port, args.tracking_uri, args.artifacts)
    store = cmd[cmd.index("--backend-store-uri") + 1]
    # a copied project's store still names the original's mlartifacts: re-point it first (sqlite only, no mlflow import)
    from workbench.tracking import relocate_store

    relocate_store(store)
    host = _probe_host(args.host)
    url = f"http://{'[' + host + ']' if ':' in host else host}:{args.port}"
    info(f"starting the MLflow UI (store: {store})")
    proc = procs.popen(procs.guarded(cmd))
    try:
        waited = wait_until_answering(url + "/", proc, args.wait_s, info)
        info(f"MLflow UI on http://{args.host}:{args.port}  (answered after {waited:.0f} s); Ctrl-C stops it")
        proc.wait()
        return proc.returncode
    except KeyboardInterrupt:
        procs.interrupted()
        info("stopping the MLflow UI...")
        return 0
    finally:
        procs.stop(proc)
