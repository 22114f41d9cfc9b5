"""Training and inference speed of the FED-LSTM: Lightning loop vs a bare PyTorch loop, latency, throughput.

    .venv/bin/python benchmarks/bench_training.py [--epochs 3] [--batches 80] [--batch-size 256]

1. Training windows per second of ``train()``'s Lightning loop (same Trainer settings, same
   LightningModule) against a bare PyTorch loop (zero_grad, forward, MSE, backward, clip, Adam
   step) on the same network and the very same batches, interleaved in one run so machine load
   hits both alike. Target: Lightning >= 0.85 x bare.
2. Single-window CPU inference latency: the net on one (1, 16, 5) window, and the whole
   LegForceModel path (numpy in, normalise, pad, predict, denormalise) for one tick.
   Target: <= 1 ms.
3. Batched inference throughput of ``LearnedLegModel.wrench`` on a (64, 1000) motion batch.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np


def _data(n_ticks: int, seq_len: int, seed: int = 0):
    import torch

    g = torch.Generator().manual_seed(seed)
    x = torch.randn(n_ticks, 5, generator=g)
    y = torch.randn(n_ticks, 6, generator=g)
    ends = np.arange(seq_len - 1, n_ticks, dtype=np.int64)
    return x, y, ends


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epochs", type=int, default=3)
    ap.add_argument("--batches", type=int, default=80, help="batches per epoch")
    ap.add_argument("--batch-size", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=2, help="interleaved bare/Lightning pairs")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch threads (default 1: a ratio of like with like; 0: torch's default)")
    args = ap.parse_args()

    import lightning.pytorch as pl
    import torch
    from torch.utils.data import BatchSampler, DataLoader

    from workbench.learn.config import LearnSettings, ModelSettings
    from workbench.learn.datamodule import WindowBatches
    from workbench.learn.legmodel import LearnedLegModel
    from workbench.learn.module import WrenchRegressor
    from workbench.learn.nets import build_net
    from workbench.learn.train import _quiet_lightning
    from workbench.learn.windows import Normalisation

    _quiet_lightning()
    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = LearnSettings()
    seq_len, bs = cfg.data.seq_len, args.batch_size
    x, y, ends = _data(200_000, seq_len)

    class _Prepared:  # the two tensors WindowBatches gathers from
        pass

    prep = _Prepared()
    prep.x, prep.y, prep.base = x, y, None
    ds = WindowBatches(prep, ends, seq_len, with_base=False)
    rng = np.random.default_rng(0)
    batches = [rng.choice(len(ends), bs, replace=False).tolist() for _ in range(args.batches)]
    windows_per_epoch = bs * len(batches)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads; FED-LSTM 2x64, seq_len {seq_len}, "
          f"batch {bs}, {len(batches)} batches/epoch, {args.epochs} epochs")

    def bare(seed: int) -> list[float]:
        torch.manual_seed(seed)
        net = build_net(cfg.model, seq_len)
        opt = torch.optim.Adam(net.parameters(), lr=cfg.optim.lr)
        net.train()
        times = []
        for _ in range(args.epochs):
            t0 = time.perf_counter()
            for idx in batches:
                xb, yb = ds[idx]
                opt.zero_grad(set_to_none=True)
                loss = torch.nn.functional.mse_loss(net(xb), yb)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.optim.grad_clip)
                opt.step()
            times.append(time.perf_counter() - t0)
        return times

    class _Timer(pl.Callback):
        def __init__(self):
            self.times = []

        def on_train_epoch_start(self, trainer, module):
            self._t0 = time.perf_counter()

        def on_train_batch_end(self, trainer, module, outputs, batch, batch_idx):
            if batch_idx == len(batches) - 1:  # stop before the epoch's validation
                self.times.append(time.perf_counter() - self._t0)

    class _Fixed(BatchSampler):  # the same batches as the bare loop, in the same order
        def __init__(self):
            pass

        def __iter__(self):
            return iter(batches)

        def __len__(self):
            return len(batches)

    def lightning(seed: int) -> list[float]:
        torch.manual_seed(seed)
        module = WrenchRegressor(build_net(cfg.model, seq_len), cfg.optim)
        timer = _Timer()
        trainer = pl.Trainer(accelerator="cpu", devices=1, max_epochs=args.epochs, logger=False,
                             enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False,
                             num_sanity_val_steps=0, gradient_clip_val=cfg.optim.grad_clip, callbacks=[timer])
        loader = DataLoader(ds, sampler=_Fixed(), batch_size=None)
        # one small validation batch per epoch feeds the plateau scheduler, as in train(); not timed
        val = DataLoader(ds, sampler=BatchSampler(range(bs), bs, False), batch_size=None)
        trainer.fit(module, train_dataloaders=loader, val_dataloaders=val)
        return timer.times

    bare(99)  # warm-up: first-call allocations, thread pools
    lightning(99)
    b_all, l_all = [], []
    for r in range(args.repeats):
        b_all += bare(r)
        l_all += lightning(r)
    b_wps = windows_per_epoch / statistics.median(b_all)
    l_wps = windows_per_epoch / statistics.median(l_all)
    ratio = l_wps / b_wps
    print(f"training: bare PyTorch {b_wps:,.0f} windows/s, Lightning {l_wps:,.0f} windows/s, "
          f"ratio {ratio:.3f} (target >= 0.85) {'OK' if ratio >= 0.85 else 'MISSED'}")

    # --- inference --------------------------------------------------------------------------
    from workbench.hydro.motion import JointSinusoid

    net = build_net(ModelSettings(), seq_len).eval()
    norm = Normalisation((0.15, -50, 20, 0, 0), (0.08, 40, 50, 150, 200), (0,) * 6, (0.1,) * 6)
    model = LearnedLegModel(net, model=ModelSettings(), seq_len=seq_len, dt_s=1 / 65, norm=norm)
    one = torch.randn(1, seq_len, 5)
    lat = []
    with torch.inference_mode():
        for _ in range(50):
            net(one)
        for _ in range(300):
            t0 = time.perf_counter()
            net(one)
            lat.append(time.perf_counter() - t0)
    js = JointSinusoid(10, -100, 80, -20, 0.5, 1.0472)
    tick = js.motion(np.array([0.0]), 0.2)
    lat_api = []
    for _ in range(20):
        model.wrench(tick)
    for _ in range(200):
        t0 = time.perf_counter()
        model.wrench(tick)
        lat_api.append(time.perf_counter() - t0)
    net_ms, api_ms = 1e3 * statistics.median(lat), 1e3 * statistics.median(lat_api)
    print(f"single-window latency: net {net_ms:.3f} ms, LegForceModel.wrench (1 tick) {api_ms:.3f} ms "
          f"(target <= 1 ms) {'OK' if max(net_ms, api_ms) <= 1.0 else 'MISSED'}")

    t = np.arange(1000) / 65
    batch = js.motion(t, 0.2)
    from workbench.hydro.motion import LegMotion

    big = LegMotion.from_arrays(batch.dt_s, np.repeat(batch.theta_h_deg, 64, 0), np.repeat(batch.theta_k_deg, 64, 0),
                                np.repeat(batch.omega_h_dps, 64, 0), np.repeat(batch.omega_k_dps, 64, 0),
                                np.repeat(batch.flow_speed_mps, 64, 0))
    model.wrench(big.rows(slice(0, 4)))
    tt = []
    for _ in range(3):
        t0 = time.perf_counter()
        model.wrench(big)
        tt.append(time.perf_counter() - t0)
    n = 64 * 1000
    print(f"batched inference: LegForceModel.wrench on (64, 1000) = {n:,} windows in {min(tt):.2f} s: "
          f"{n / min(tt):,.0f} windows/s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
