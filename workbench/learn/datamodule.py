"""The Lightning DataModule: windows of the processed data, split by parameter set, normalised on train.

The run table is normalised once into two float32 tensors; a batch is gathered from them by
window end rows (``rows = ends[:, None] + arange(-L+1, 1)``), so no window is stored twice.
Training windows come from training runs (measured and interpolated); validation and test
windows from measured runs only. Training draws ``train_windows_per_epoch`` windows at random
each epoch (fresh ones every epoch) when the campaign is larger than an epoch should be.
"""

from __future__ import annotations

from dataclasses import dataclass

import lightning.pytorch as pl
import numpy as np
import torch
from torch.utils.data import BatchSampler, DataLoader, Dataset, RandomSampler, SequentialSampler

from workbench.errors import DataError
from workbench.learn.config import DataSettings
from workbench.learn.split import ParameterSplit, split_parameter_sets
from workbench.learn.windows import Normalisation, RunTable, fit_normalisation, window_ends, with_ef


@dataclass(frozen=True)
class PreparedData:
    """A run table with its split, its training normalisation and the normalised tensors."""

    table: RunTable
    split: ParameterSplit
    norm: Normalisation
    #: (N, 5) normalised inputs
    x: torch.Tensor
    #: (N, 6) normalised wrench
    y: torch.Tensor
    #: (N, 6) EF wrench in the same normalised units, or None (only the hybrid needs it)
    base: torch.Tensor | None

    def runs(self, name: str) -> np.ndarray:
        """Run indices of a split: training keeps interpolated runs, validation and test do not."""
        return self.split.runs(self.table, name, measured_only=(name != "train"))

    @property
    def dt_s(self) -> float:
        """Median control tick interval of the measured training runs (the model's tick)."""
        runs = self.split.runs(self.table, "train", measured_only=True)
        runs = runs if len(runs) else self.runs("train")
        return float(np.median(self.table.runs["dt_s"].to_numpy()[runs]))


def prepare_data(table: RunTable, cfg: DataSettings, *, need_ef: bool = False,
                 split: ParameterSplit | None = None) -> PreparedData:
    """Split by parameter set (or reuse ``split``), fit the normalisation on training runs, normalise once."""
    if split is None:
        split = split_parameter_sets(table, cfg.split.fractions, cfg.split.seed, cfg.split.pin_test,
                                     stratify=cfg.split.stratify)
    train_runs = split.runs(table, "train", measured_only=False)
    if len(train_runs) == 0:
        raise DataError("no training runs after the split")
    norm = fit_normalisation(table, train_runs)
    xm, xs, ym, ys = norm.arrays()
    x = torch.from_numpy((table.x - xm) / xs)
    y = torch.from_numpy((table.y - ym) / ys)
    base = None
    if need_ef:
        table = with_ef(table)
        base = torch.from_numpy((table.ef - ym) / ys)
    return PreparedData(table, split, norm, x, y, base)


class WindowBatches(Dataset):
    """Map-style dataset whose item is a whole batch: a list of window numbers -> (x, y[, base])."""

    def __init__(self, data: PreparedData, ends: np.ndarray, seq_len: int, with_base: bool):
        self.x, self.y = data.x, data.y
        self.base = data.base if with_base else None
        self.ends = torch.from_numpy(np.asarray(ends, dtype=np.int64))
        self.offsets = torch.arange(-seq_len + 1, 1, dtype=torch.int64)

    def __len__(self) -> int:
        return len(self.ends)

    def __getitem__(self, idx):
        e = self.ends[torch.as_tensor(idx, dtype=torch.int64)]
        xb = self.x[e[:, None] + self.offsets]
        if self.base is None:
            return xb, self.y[e]
        return xb, self.y[e], self.base[e]


class WindowDataModule(pl.LightningDataModule):
    """Train/val/test loaders of windows over a :class:`PreparedData`."""

    def __init__(self, data: PreparedData, cfg: DataSettings, *, with_base: bool = False, seed: int = 0):
        super().__init__()
        self.data, self.cfg, self.with_base, self.seed = data, cfg, with_base, seed
        self.ends = {name: window_ends(data.table, data.runs(name), cfg.seq_len) for name in ("train", "val", "test")}
        for name in ("train", "val"):
            if len(self.ends[name]) == 0:
                raise DataError(f"no {name} windows of {cfg.seq_len} ticks",
                                hint="runs shorter than data.seq_len, or too few parameter sets")

    def _loader(self, name: str, shuffle: bool) -> DataLoader:
        ds = WindowBatches(self.data, self.ends[name], self.cfg.seq_len, self.with_base)
        if shuffle:
            g = torch.Generator().manual_seed(self.seed)
            n = self.cfg.train_windows_per_epoch
            sampler = RandomSampler(ds, num_samples=min(n, len(ds)) if n else None, generator=g)
            bs = self.cfg.batch_size
        else:
            sampler, bs = SequentialSampler(ds), self.cfg.eval_batch_size
        return DataLoader(ds, sampler=BatchSampler(sampler, bs, drop_last=False), batch_size=None)

    def train_dataloader(self) -> DataLoader:
        """Shuffled training windows (a fresh random draw each epoch)."""
        return self._loader("train", True)

    def val_dataloader(self) -> DataLoader:
        """All validation windows, in order."""
        return self._loader("val", False)

    def test_dataloader(self) -> DataLoader:
        """All test windows, in order."""
        return self._loader("test", False)

    def windows_per_epoch(self) -> int:
        """Training windows one epoch visits."""
        n = self.cfg.train_windows_per_epoch
        return min(n, len(self.ends["train"])) if n else len(self.ends["train"])
