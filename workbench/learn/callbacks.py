"""Lightning callbacks of the training loop: per-epoch report and MLflow curves, best weights in memory."""

from __future__ import annotations

import copy
import math
import time
from typing import Callable

import lightning.pytorch as pl


class EpochLog(pl.Callback):
    """One line per epoch (loss, val loss, lr, windows/s), the learning curve, and MLflow metrics per epoch."""

    def __init__(self, max_epochs: int, report: Callable[[str], None] | None = None, mlflow_run: bool = False,
                 prefix: str = ""):
        self.max_epochs, self.report, self.mlflow_run, self.prefix = max_epochs, report, mlflow_run, prefix
        self.history: list[dict] = []
        self._t0 = 0.0
        self._train_s = 0.0
        self._windows = 0

    def on_train_epoch_start(self, trainer, pl_module):
        """Start the epoch clock."""
        self._t0 = time.perf_counter()
        self._windows = 0

    def on_train_batch_end(self, trainer, pl_module, outputs, batch, batch_idx):
        """Count windows."""
        self._windows += int(batch[0].shape[0])

    def on_validation_epoch_start(self, trainer, pl_module):
        """Stop the training clock (validation is not training throughput)."""
        if not trainer.sanity_checking:
            self._train_s = time.perf_counter() - self._t0

    def on_train_epoch_end(self, trainer, pl_module):
        """Report and record the epoch (train and val loss are both logged by now)."""
        m = trainer.callback_metrics
        lr = trainer.optimizers[0].param_groups[0]["lr"] if trainer.optimizers else float("nan")
        row = {"epoch": trainer.current_epoch + 1,
               "train_loss": float(m.get("train_loss", float("nan"))),
               "val_loss": float(m.get("val_loss", float("nan"))),
               "lr": float(lr), "windows_per_s": self._windows / self._train_s if self._train_s > 0 else float("nan"),
               "epoch_s": time.perf_counter() - self._t0}
        self.history.append(row)
        if self.report:
            self.report(f"{self.prefix}epoch {row['epoch']:>3}/{self.max_epochs}  loss {row['train_loss']:.4f}  "
                        f"val {row['val_loss']:.4f}  lr {row['lr']:.1e}  {row['windows_per_s']:,.0f} windows/s  "
                        f"{row['epoch_s']:.1f} s")
        if self.mlflow_run:
            from workbench.tracking import log_metrics

            log_metrics({k: v for k, v in row.items() if k != "epoch" and math.isfinite(v)}, step=row["epoch"])


class BestWeights(pl.Callback):
    """Keep a copy of the weights of the epoch with the lowest validation loss (no checkpoint files)."""

    def __init__(self, monitor: str = "val_loss"):
        self.monitor = monitor
        self.best = math.inf
        self.best_epoch = 0
        self.state: dict | None = None

    def on_validation_end(self, trainer, pl_module):
        """Copy the weights when the validation loss improved."""
        if trainer.sanity_checking:
            return
        v = trainer.callback_metrics.get(self.monitor)
        if v is not None and float(v) < self.best:
            self.best = float(v)
            self.best_epoch = trainer.current_epoch + 1
            self.state = copy.deepcopy(pl_module.state_dict())

    def restore(self, pl_module) -> None:
        """Load the best weights back into the module."""
        if self.state is not None:
            pl_module.load_state_dict(self.state)
