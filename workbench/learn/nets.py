"""Plain ``nn.Module`` networks mapping a window of ticks (B, L, 5) to the wrench at its last tick (B, 6).

* :class:`RecurrentRegressor` — the paper's FED-LSTM (``cell="lstm"``, 2 layers of 64, dropout
  0.21, a fully connected head on the last step's hidden state) and its GRU twin.
* :class:`WindowMLP` — a feed-forward net on the flattened window: no recurrence, the cheapest
  to run, and the baseline that tells whether recurrence earns its cost.

The EF-residual hybrid is not a separate net: any of these learns the measured wrench minus the
EF (see :mod:`workbench.learn.module`), so the physics prior sets the trend and the net the rest.
Inputs and outputs are normalised (see :class:`workbench.learn.windows.Normalisation`).
"""

from __future__ import annotations

import torch
from torch import nn

from workbench.learn.config import FEATURES, ModelSettings


class RecurrentRegressor(nn.Module):
    """LSTM/GRU layers, dropout, and a linear head on the last time step."""

    def __init__(self, n_in: int = len(FEATURES), n_out: int = 6, hidden_size: int = 64, num_layers: int = 2,
                 dropout: float = 0.21, cell: str = "lstm"):
        super().__init__()
        rnn = {"lstm": nn.LSTM, "gru": nn.GRU}[cell]
        self.rnn = rnn(n_in, hidden_size, num_layers, batch_first=True, dropout=dropout if num_layers > 1 else 0.0)
        self.drop = nn.Dropout(dropout)
        self.head = nn.Linear(hidden_size, n_out)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, L, n_in) -> (B, n_out)."""
        out, _ = self.rnn(x)
        return self.head(self.drop(out[:, -1]))


class WindowMLP(nn.Module):
    """``num_layers`` hidden layers of ``hidden_size`` (GELU, dropout) on the flattened window."""

    def __init__(self, seq_len: int, n_in: int = len(FEATURES), n_out: int = 6, hidden_size: int = 128,
                 num_layers: int = 2, dropout: float = 0.1):
        super().__init__()
        layers: list[nn.Module] = [nn.Flatten()]
        width = seq_len * n_in
        for _ in range(num_layers):
            layers += [nn.Linear(width, hidden_size), nn.GELU(), nn.Dropout(dropout)]
            width = hidden_size
        layers.append(nn.Linear(width, n_out))
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, L, n_in) -> (B, n_out)."""
        return self.net(x)


def build_net(model: ModelSettings, seq_len: int) -> nn.Module:
    """The network a configuration names (the hybrid uses its backbone)."""
    kind = model.backbone if model.variant == "ef_residual" else model.variant
    if kind == "mlp":
        return WindowMLP(seq_len, hidden_size=model.hidden_size, num_layers=model.num_layers, dropout=model.dropout)
    return RecurrentRegressor(hidden_size=model.hidden_size, num_layers=model.num_layers, dropout=model.dropout,
                              cell=kind)
