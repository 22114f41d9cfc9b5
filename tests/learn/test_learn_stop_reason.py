"""Training says why it stopped: all epochs, early stopping (patience) or the time cap, in metrics.json and MLflow."""

from __future__ import annotations

import json

import pytest
from learn_helpers import tiny_config


@pytest.fixture(scope="module")
def prepared(frame):
    from workbench.learn.config import DataSettings
    from workbench.learn.datamodule import prepare_data
    from workbench.learn.windows import table_from_frame

    return prepare_data(table_from_frame(frame), DataSettings(), need_ef=False)


def test_all_epochs_run_is_reported_as_max_epochs(prepared, parquet, tmp_path):
    from workbench.learn.train import train

    cfg = tiny_config(parquet, tmp_path, **{"tracking.enabled": False, "trainer.max_epochs": 2})
    metrics, objects = train(cfg, prepared=prepared)
    assert metrics["stop_reason"] == "max_epochs" and metrics["epochs"] == 2
    saved = json.loads(objects["card"]["metrics.json"])  # the model folder's metrics.json, as the command writes it
    assert saved["stop_reason"] == "max_epochs" and saved["stop_detail"] == "max_epochs=2 reached"


def test_a_worsening_validation_loss_is_reported_as_early_stopping(prepared, parquet, tmp_path):
    import lightning.pytorch as pl
    import torch

    from workbench.learn.train import train

    class Worsening(pl.Callback):  # planted: val_loss = 1 + epoch, never improves after the first
        def on_validation_end(self, trainer, pl_module):
            trainer.callback_metrics["val_loss"] = torch.tensor(1.0 + trainer.current_epoch)

    cfg = tiny_config(parquet, tmp_path, **{"tracking.enabled": False, "model_dir": None, "trainer.max_epochs": 10,
                                            "trainer.early_stop_patience": 2})
    metrics, _ = train(cfg, prepared=prepared, callbacks=[Worsening()])
    assert metrics["stop_reason"] == "early_stopping"
    assert metrics["epochs"] == 3  # epoch 1 best, 2 and 3 worse: patience 2 used up
    assert "patience" in metrics["stop_detail"] and "after epoch 3 of max_epochs=10" in metrics["stop_detail"]


@pytest.mark.slow
def test_the_time_cap_is_reported_and_tagged(prepared, parquet, tmp_path, monkeypatch):
    from mlflow import MlflowClient

    from workbench.learn.train import train

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'mlflow.db'}")
    monkeypatch.setenv("WORKBENCH_HOME", str(tmp_path))
    cfg = tiny_config(parquet, tmp_path, **{"trainer.max_epochs": 1000, "trainer.max_time_s": 3,
                                            "tracking.register": False, "model_dir": None})
    metrics, objects = train(cfg, prepared=prepared)
    assert metrics["stop_reason"] == "time_cap"
    assert metrics["epochs"] < 1000
    assert metrics["stop_detail"].startswith("time cap max_time_s=3 reached after epoch")
    tags = MlflowClient(f"sqlite:///{tmp_path / 'mlflow.db'}").get_run(objects["run_id"]).data.tags
    assert tags["stop_reason"] == "time_cap" and tags["stop_detail"] == metrics["stop_detail"]
