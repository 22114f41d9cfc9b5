"""``workbench ui``: the MLflow UI over the project's tracking store, on loopback by default."""

from __future__ import annotations

from workbench.commands._help import add_verb


def register(sub) -> None:
    """Add the ``ui`` verb."""
    p = add_verb(
        sub, "ui", help="open the MLflow UI over the project's runs and models",
        description="Start the MLflow UI on this machine over the project's tracking store "
        "(mlflow.db and mlartifacts/ at the project root, or --tracking-uri). It listens on the "
        "loopback interface only unless --host says otherwise. Stop it with Ctrl-C.",
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


def run(args) -> int:
    """Run the server in the foreground until Ctrl-C."""
    import subprocess

    from workbench.console import info

    cmd = server_command(args.host, args.port, args.tracking_uri, args.artifacts)
    info(f"MLflow UI on http://{args.host}:{args.port}  (store: {cmd[cmd.index('--backend-store-uri') + 1]}); "
         "Ctrl-C stops it")
    try:
        return subprocess.call(cmd)
    except KeyboardInterrupt:
        return 0
