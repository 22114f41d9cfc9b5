"""The LightningModule: any window net, MSE on normalised channels, Adam with plateau LR reduction.

The prediction is ``net(x) + base``: base is zero for the plain variants and the EF wrench (in
the same normalised units) for the EF-residual hybrid, so the hybrid's net learns only what the
EF misses. The loss weighs the six channels equally in units of their training standard
deviation (forces are ~10x torques in SI). The learning rate starts at ``lr`` (clipped into
[lr_min, lr_max], the paper's 1e-3..1e-1) and is cut by ``plateau_factor`` when the
validation loss stalls, never below ``lr_min``.
"""

from __future__ import annotations

import lightning.pytorch as pl
import torch
from torch import nn

from workbench.learn.config import OptimSettings


class WrenchRegressor(pl.LightningModule):
    """Train a window net on (x, y[, base]) batches."""

    def __init__(self, net: nn.Module, optim: OptimSettings):
        super().__init__()
        self.net = net
        self.optim = optim
        self._train_sum = torch.zeros(())
        self._train_n = 0
        self._val_sse = torch.zeros(())
        self._val_n = 0

    def forward(self, x: torch.Tensor, base: torch.Tensor | None = None) -> torch.Tensor:
        """Normalised wrench (B, 6)."""
        out = self.net(x)
        return out if base is None else out + base

    def _loss(self, batch) -> tuple[torch.Tensor, int]:
        x, y = batch[0], batch[1]
        pred = self(x, batch[2] if len(batch) > 2 else None)
        return torch.nn.functional.mse_loss(pred, y), len(y)

    def training_step(self, batch, batch_idx):
        """One optimisation step; the epoch mean is logged after validation (per-step logging costs time)."""
        loss, n = self._loss(batch)
        self._train_sum += loss.detach() * n
        self._train_n += n
        return loss

    def validation_step(self, batch, batch_idx):
        """Accumulate the validation squared error."""
        loss, n = self._loss(batch)
        self._val_sse += loss.detach() * n
        self._val_n += n

    def on_validation_epoch_end(self) -> None:
        """Log the validation loss (mean over windows and channels) and the epoch's mean training loss.

        Both are logged here, at the end of the validation that closes each training epoch, so that
        callbacks see them together at ``on_train_epoch_end``.
        """
        if self._val_n:
            self.log("val_loss", self._val_sse / self._val_n)
        if self._train_n:
            self.log("train_loss", self._train_sum / self._train_n)
        self._val_sse = torch.zeros(())
        self._val_n = 0
        self._train_sum = torch.zeros(())
        self._train_n = 0

    def configure_optimizers(self):
        """Adam + ReduceLROnPlateau on val_loss, bounded by [lr_min, lr_max]."""
        o = self.optim
        lr = min(max(o.lr, o.lr_min), o.lr_max)
        opt = torch.optim.Adam(self.parameters(), lr=lr, weight_decay=o.weight_decay)
        sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, mode="min", factor=o.plateau_factor,
                                                           patience=o.plateau_patience, min_lr=o.lr_min)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "monitor": "val_loss", "interval": "epoch"}}
