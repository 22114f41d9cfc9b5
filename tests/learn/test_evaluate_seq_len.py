"""`workbench evaluate` with two saved model folders by path (32- and 16-tick windows; issue 14.6): both scored
on the same ticks, each model's folder recorded, and the per-model numbers those of the model alone."""

from __future__ import annotations

import json

import numpy as np
import pytest
from learn_helpers import CONFIG

from workbench.cli import main


def _saved(folder, seq_len, seed):
    """A FED-LSTM with random weights on the real code path, saved as `workbench train` saves one."""
    import torch

    from workbench.learn.config import ModelSettings
    from workbench.learn.legmodel import LearnedLegModel, save_model
    from workbench.learn.nets import build_net
    from workbench.learn.windows import Normalisation

    torch.manual_seed(seed)
    cfg = ModelSettings(variant="ef_residual", hidden_size=8, num_layers=1, dropout=0.0, backbone="lstm")
    norm = Normalisation((0.1, -45.0, 0.0, 0.0, 0.0), (0.1, 30.0, 50.0, 100.0, 200.0), (0.0,) * 6,
                         (0.03, 0.03, 0.03, 0.003, 0.003, 0.003))
    folder.mkdir(parents=True)
    save_model(LearnedLegModel(build_net(cfg, seq_len), model=cfg, seq_len=seq_len, dt_s=1 / 65, norm=norm), folder)
    return folder


@pytest.mark.slow
def test_two_folders_scored_on_the_same_ticks(parquet, tmp_path, capsys):
    from workbench.learn.split import split_parameter_sets
    from workbench.learn.windows import read_table

    _, measured = parquet
    split = tmp_path / "split.json"
    split.write_text(json.dumps(split_parameter_sets(read_table([measured]), seed=0).to_dict()))
    m32, m16 = _saved(tmp_path / "fed-lstm", 32, 0), _saved(tmp_path / "fed-lstm-16", 16, 1)
    out = tmp_path / "both.json"
    assert main(["evaluate", "--config", str(CONFIG), "--data", str(measured), "--split", str(split),
                 "--model", str(m32), "--also", f"lstm16={m16}", "--out", str(out), "--no-mlflow"]) == 0
    err = capsys.readouterr().err
    assert f"models: lstm: {m32}; lstm16: {m16}" in err
    both = json.loads(out.read_text())
    assert set(both) == {"ef", "lstm", "lstm16"}
    assert both["lstm"]["model"]["model_path"] == str(m32) and both["lstm16"]["model"]["model_path"] == str(m16)
    assert both["lstm"]["model"]["seq_len"] == 32 and both["lstm16"]["model"]["seq_len"] == 16
    # one call: every model skips the longest window's start-up (31 ticks), so the numbers compare
    assert {both[k]["skipped_ticks_per_run"] for k in both} == {31}
    assert len({both[k]["n_ticks"] for k in both}) == 1
    assert not np.allclose(list(both["lstm"]["mse"].values()), list(both["lstm16"]["mse"].values()))
    # alone, the 16-tick model skips only 15 ticks: a different tick set, which is why the report uses one call
    alone = tmp_path / "alone.json"
    assert main(["evaluate", "--config", str(CONFIG), "--data", str(measured), "--split", str(split),
                 "--model", str(m16), "--out", str(alone), "--no-mlflow"]) == 0
    one = json.loads(alone.read_text())
    assert one["lstm"]["skipped_ticks_per_run"] == 15 and one["lstm"]["n_ticks"] > both["lstm16"]["n_ticks"]
    n_runs = both["lstm"]["n_runs"]
    assert one["lstm"]["n_ticks"] - both["lstm16"]["n_ticks"] == n_runs * 16
    # the 16-tick model's predictions do not depend on the company it is evaluated in: its per-run MSE over the
    # shared ticks equals the one recomputed here from its own predictions on those ticks
    assert both["lstm16"]["mse"]["fy_n"] == pytest.approx(_mse_from_scratch(m16, measured, split, skip=31), rel=1e-9)


def _mse_from_scratch(folder, data, split_path, skip):
    """Pooled f_y MSE of a model on the split's test runs, from its own predictions (formula written here)."""
    from workbench.hydro.legmodel import load_leg_model
    from workbench.learn.split import ParameterSplit
    from workbench.learn.windows import motion_of_run, read_table

    table = read_table([data])
    split = ParameterSplit.from_dict(json.loads(split_path.read_text()))
    model = load_leg_model(str(folder))
    sse, n = 0.0, 0
    for r in split.runs(table, "test", measured_only=True):
        pred = model.wrench(motion_of_run(table, int(r)))[0]
        measured = np.asarray(table.y[table.run_slice(int(r))], dtype=np.float64)
        err = pred[skip:, 1] - measured[skip:, 1]
        sse += float((err ** 2).sum())
        n += len(err)
    return sse / n
