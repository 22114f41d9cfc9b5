"""Each variant trains and reduces loss; the LegForceModel adapter is shaped, causal and saved faithfully."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from learn_helpers import tiny_config

from workbench.hydro.motion import JointSinusoid, LegMotion


@pytest.fixture(scope="module")
def prepared(frame):
    from workbench.learn.config import DataSettings
    from workbench.learn.datamodule import prepare_data
    from workbench.learn.windows import table_from_frame

    return prepare_data(table_from_frame(frame), DataSettings(), need_ef=True)


def _val_loss(module, dm) -> float:
    import torch

    sse, n = 0.0, 0
    module.eval()
    with torch.inference_mode():
        for batch in dm.val_dataloader():
            pred = module(batch[0], batch[2] if len(batch) > 2 else None)
            sse += float(((pred - batch[1]) ** 2).mean(1).sum())
            n += len(batch[1])
    return sse / n


@pytest.mark.parametrize("variant", ["lstm", "gru", "mlp", "ef_residual"])
def test_each_variant_trains_and_reduces_loss(variant, prepared, parquet, tmp_path):
    import lightning.pytorch as pl

    from workbench.learn.datamodule import WindowDataModule
    from workbench.learn.module import WrenchRegressor
    from workbench.learn.nets import build_net
    from workbench.learn.train import train

    cfg = tiny_config(parquet, tmp_path, **{"model.variant": variant, "tracking.enabled": False, "model_dir": None,
                                            "trainer.max_epochs": 3})
    pl.seed_everything(0, verbose=False)
    dm = WindowDataModule(prepared, cfg.data, with_base=variant == "ef_residual")
    before = _val_loss(WrenchRegressor(build_net(cfg.model, cfg.data.seq_len), cfg.optim), dm)
    metrics, objects = train(cfg, prepared=prepared)
    assert metrics["best_val_loss"] < 0.6 * before, (before, metrics["best_val_loss"])
    assert metrics["epochs"] == 3 and len(objects["history"]) == 3
    # scored on the held-out sets through the LegForceModel interface, EF alongside
    assert set(metrics["test"]) == {"lstm", "ef"}
    assert metrics["test"]["lstm"]["n_ticks"] == metrics["test"]["ef"]["n_ticks"] > 0


@pytest.fixture(scope="module")
def trained(prepared, parquet, tmp_path_factory):
    """(cfg, metrics, objects) of a tiny training whose configuration names a model folder."""
    from workbench.learn.train import train

    root = tmp_path_factory.mktemp("m")
    cfg = tiny_config(parquet, root, **{"tracking.enabled": False, "model_dir": str(root / "model")})
    metrics, objects = train(cfg, prepared=prepared)
    return cfg, metrics, objects


@pytest.fixture(scope="module")
def model(trained):
    return trained[2]["model"]


def test_train_writes_nothing_and_its_card_written_by_the_command_reloads(trained, prepared, tmp_path):
    """Issue 17.2: train(cfg) returns the model folder as bytes; the command writes it, atomically, as one set."""
    import csv
    import io
    import json

    from workbench.atomic import read_marker
    from workbench.commands.train import write_model_card
    from workbench.learn.legmodel import load_model

    cfg, metrics, objects = trained
    root = Path(cfg.model_dir).parent
    assert not Path(cfg.model_dir).exists() and sorted(p.name for p in root.iterdir()) == []
    card = objects["card"]
    assert set(card) == {"model.json", "weights.pt", "config.json", "split.json", "metrics.json", "history.csv",
                         "learning_curve.png"}
    assert card["learning_curve.png"].startswith(b"\x89PNG\r\n\x1a\n")
    rows = list(csv.DictReader(io.StringIO(card["history.csv"].decode())))
    assert len(rows) == metrics["epochs"] == cfg.trainer.max_epochs
    assert json.loads(card["metrics.json"])["best_val_loss"] == pytest.approx(metrics["best_val_loss"])
    assert json.loads(card["split.json"]) == prepared.split.to_dict(prepared.table)

    out = write_model_card(tmp_path / "model", card)
    assert {p.name for p in out.iterdir()} == set(card) | {".workbench-output.json"}
    assert read_marker(out)["verb"] == "train"
    m = _motion(np.arange(100) / 65)
    assert np.array_equal(load_model(out).wrench(m), objects["model"].wrench(m))


def _motion(t_s, speed=0.2, params=(10.0, -100.0, 80.0, -20.0, 0.5, 1.0472)):
    return JointSinusoid(*params).motion(np.asarray(t_s), speed)


def test_adapter_shape_and_units(model, prepared):
    t = np.arange(200) / 65
    m1, m2 = _motion(t, 0.1), _motion(t, 0.2, (-50.0, -100.0, 80.0, -60.0, 0.5, 1.0472))
    both = LegMotion.from_arrays(m1.dt_s, np.vstack([m1.theta_h_deg, m2.theta_h_deg]),
                                 np.vstack([m1.theta_k_deg, m2.theta_k_deg]), np.vstack([m1.omega_h_dps, m2.omega_h_dps]),
                                 np.vstack([m1.omega_k_dps, m2.omega_k_dps]), np.vstack([m1.flow_speed_mps,
                                                                                        m2.flow_speed_mps]))
    w = model.wrench(both)
    assert w.shape == (2, 200, 6) and np.isfinite(w).all()
    # a batch row equals the same motion alone (no cross-talk between rows)
    assert np.allclose(w[1], model.wrench(m2)[0], atol=1e-5)
    # physical units: same order of magnitude as the training wrench
    assert 0.1 < np.abs(w[..., 1]).max() / np.abs(prepared.table.y[:, 1]).max() < 10


def test_adapter_is_causal_and_pads_with_the_first_tick(model):
    t = np.arange(120) / 65
    m = _motion(t)
    base = model.wrench(m)[0]
    # change the future from tick 60 on: outputs before 60 must not move
    th = m.theta_h_deg.copy()
    th[:, 60:] += 30.0
    changed = model.wrench(LegMotion.from_arrays(m.dt_s, th, m.theta_k_deg, m.omega_h_dps, m.omega_k_dps,
                                                 m.flow_speed_mps))[0]
    assert np.array_equal(base[:60], changed[:60])
    assert not np.allclose(base[60:], changed[60:])
    # tick 0 sees 16 copies of the first tick: the same as a motion that rested there
    rest = LegMotion.from_arrays(m.dt_s, np.full((1, 16), m.theta_h_deg[0, 0]), np.full((1, 16), m.theta_k_deg[0, 0]),
                                 np.full((1, 16), m.omega_h_dps[0, 0]), np.full((1, 16), m.omega_k_dps[0, 0]), 0.2)
    assert np.allclose(base[0], model.wrench(rest)[0, -1], atol=1e-6)


def test_adapter_resamples_other_tick_rates(model):
    t65 = np.arange(260) / 65
    t_fine = np.arange(0, t65[-1] + 1e-9, 0.001)
    coarse = model.wrench(_motion(t65))[0]
    fine = model.wrench(_motion(t_fine))[0]
    assert fine.shape == (len(t_fine), 6)
    on_coarse = np.stack([np.interp(t65, t_fine, fine[:, k]) for k in range(6)], -1)
    scale = np.abs(coarse[40:]).max(0)
    assert np.all(np.abs(on_coarse[40:] - coarse[40:]).max(0) < 0.05 * scale)


def test_saved_folder_reloads_identically(model, tmp_path):
    from workbench.errors import ModelLoadError
    from workbench.learn.legmodel import load_model, save_model

    save_model(model, tmp_path)
    again = load_model(tmp_path)
    m = _motion(np.arange(100) / 65)
    assert np.array_equal(model.wrench(m), again.wrench(m))
    assert again.describe()["variant"] == "lstm" and again.seq_len == model.seq_len
    (tmp_path / "weights.pt").write_bytes(b"garbage")
    with pytest.raises(ModelLoadError, match="weights.pt does not load"):
        load_model(tmp_path)
    with pytest.raises(ModelLoadError, match="not a trained leg model folder"):
        load_model(tmp_path / "nothing")
