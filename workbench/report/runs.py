"""Report section linking the latest MLflow run of each pipeline step."""

from __future__ import annotations

from workbench.report.page import Section

#: the pipeline's MLflow experiments in the order the data flows (others in the store follow by name)
MLFLOW_EXPERIMENTS = ("fed-lstm", "fed-lstm-tune", "evaluate", "optimize", "diagnose")


def mlflow_section(tracking_uri: str | None, ui_url: str) -> Section:
    """Links to the latest MLflow run of each pipeline step (open with `workbench ui`)."""
    sec = Section("MLflow runs")
    try:
        from mlflow.tracking import MlflowClient

        from workbench.project import mlflow_tracking_uri

        client = MlflowClient(tracking_uri=mlflow_tracking_uri(tracking_uri))
        order = {name: i for i, name in enumerate(MLFLOW_EXPERIMENTS)}
        exps = sorted(client.search_experiments(), key=lambda e: (order.get(e.name, len(order)), e.name))
        for exp in exps:
            runs = client.search_runs([exp.experiment_id], order_by=["attributes.start_time DESC"], max_results=5)
            for r in runs:
                # a pruned Optuna trial ends KILLED, tagged state=pruned (workbench.learn.tune): say which
                state = r.data.tags.get("state") if r.info.status == "KILLED" else None
                label = f"{exp.name}: {r.info.run_name} ({state or r.info.status.lower()})"
                sec.links.append((label, f"{ui_url}/#/experiments/{exp.experiment_id}/runs/{r.info.run_id}"))
    except Exception as exc:  # a report without links is still a report
        sec.paragraphs.append(f"MLflow store not readable: {type(exc).__name__}: {exc}")
    if not sec.links and not sec.paragraphs:
        sec.paragraphs.append("No MLflow runs yet.")
    sec.paragraphs.append(f"Start the UI with `workbench ui`, then open {ui_url}.")
    return sec
