"""Windows, split by parameter set and normalisation: the data side of the FED-LSTM (no torch)."""

from __future__ import annotations

import json

import numpy as np
import polars as pl
import pytest
from learn_helpers import make_frame

from workbench.errors import ContractError, DataError
from workbench.learn.split import ParameterSplit, split_parameter_sets
from workbench.learn.windows import fit_normalisation, read_table, table_from_frame, window_ends


def test_windows_never_cross_runs(frame):
    table = table_from_frame(frame)
    runs = np.arange(table.n_runs)
    for L in (1, 16, 40):
        ends = window_ends(table, runs, L)
        run_of_end = np.searchsorted(table.start, ends, side="right") - 1
        run_of_first = np.searchsorted(table.start, ends - L + 1, side="right") - 1
        assert np.array_equal(run_of_end, run_of_first)
        assert len(ends) == int(np.sum(table.length - (L - 1)))  # every full window, once
        assert len(np.unique(ends)) == len(ends)


def test_row_order_does_not_matter_and_interpolated_runs_are_their_own(frame):
    a = table_from_frame(frame)
    b = table_from_frame(frame.sample(fraction=1.0, shuffle=True, seed=3))
    assert np.array_equal(a.x, b.x) and np.array_equal(a.y, b.y)
    # interpolation that reuses one run id for two synthetic speeds still gives two runs
    one = frame.filter(pl.col("run_id") == "r0003")
    twin = one.with_columns(pl.lit(0.17).alias("flow_speed_mps"))
    t = table_from_frame(pl.concat([one, twin]))
    assert t.n_runs == 2 and sorted(t.runs["flow_speed_mps"].to_list()) == [0.15, 0.17]


def test_time_must_increase_within_a_run(frame):
    r = frame.filter(pl.col("run_id") == "r0001")
    with pytest.raises(DataError, match="run r0001.*strictly increasing"):
        table_from_frame(pl.concat([r, r.head(5)]))


def test_bad_files_give_one_line_errors(tmp_path, frame):
    p = tmp_path / "bad.parquet"
    frame.drop("theta_k_deg").write_parquet(p)
    with pytest.raises(ContractError, match=r"bad.parquet: missing columns theta_k_deg"):
        read_table([p])
    nan = frame.with_columns(pl.when(pl.col("run_id") == "r0004").then(float("nan")).otherwise(pl.col("fy_n"))
                             .alias("fy_n"))
    nan.write_parquet(p)
    with pytest.raises(DataError, match="run r0004: non-finite"):
        read_table([p])
    with pytest.raises(ContractError, match="not found"):
        read_table([tmp_path / "nope.parquet"])


def test_split_is_by_parameter_set_seeded_and_recorded():
    f = make_frame(theta_h_min=(10.0, -10.0, -30.0, -50.0), theta_k_max=(-20.0, -40.0, -60.0, -80.0),
                   freqs=(0.3, 0.5, 0.6), speeds=(0.0, 0.2), cycles=1.0, interpolated_speeds=(0.1,))
    table = table_from_frame(f)
    sp = split_parameter_sets(table, (0.7, 0.1, 0.2), seed=0)
    counts = sp.counts()
    assert sum(counts.values()) == 48 and counts == {"train": 33, "val": 5, "test": 10}
    # every run of a set (all speeds, measured or interpolated) is in its set's split
    by_set: dict[tuple, set] = {}
    for r in range(table.n_runs):
        key = tuple(table.runs["set_key"][r])
        by_set.setdefault(key, set()).add(sp.assignment[key])
    assert all(len(s) == 1 for s in by_set.values())
    names = {n: set(sp.runs(table, n, measured_only=False).tolist()) for n in ("train", "val", "test")}
    assert not (names["train"] & names["val"]) and not (names["train"] & names["test"]) and not (names["val"] & names["test"])
    assert not table.runs["interpolated"].to_numpy()[sp.runs(table, "test", measured_only=True)].any()
    # seeded: same seed same split whatever the row order, another seed another split
    again = split_parameter_sets(table_from_frame(f.sample(fraction=1.0, shuffle=True, seed=9)), seed=0)
    assert again.assignment == sp.assignment
    assert split_parameter_sets(table, seed=1).assignment != sp.assignment
    # recorded: the JSON record reads back to the same split and lists the runs
    rec = json.loads(json.dumps(sp.to_dict(table)))
    assert ParameterSplit.from_dict(rec).assignment == sp.assignment
    assert rec["counts"] == counts and all(s["runs"] for s in rec["sets"])


def test_stratified_split_gives_val_and_test_every_frequency():
    # 3 frequencies x 16 sets: a plain draw can leave a frequency out of val (5 sets); a stratified one
    # gives each frequency its share of val (1-2) and test (3-4) for every seed
    f = make_frame(theta_h_min=(10.0, -10.0, -30.0, -50.0), theta_k_max=(-20.0, -40.0, -60.0, -80.0),
                   freqs=(0.3, 0.45, 0.6), speeds=(0.1,), cycles=1.0)
    table = table_from_frame(f)
    plain_misses = 0
    for seed in range(12):
        sp = split_parameter_sets(table, (0.7, 0.1, 0.2), seed=seed, stratify=("frequency_hz",))
        assert sp.counts() == {"train": 33, "val": 5, "test": 10}
        for name, lo, hi in (("val", 1, 2), ("test", 3, 4)):
            per = [sum(1 for k in sp.sets(name) if sp.params[k]["frequency_hz"] == fr) for fr in (0.3, 0.45, 0.6)]
            assert all(lo <= n <= hi for n in per), (seed, name, per)
        plain = split_parameter_sets(table, (0.7, 0.1, 0.2), seed=seed)
        plain_misses += len({plain.params[k]["frequency_hz"] for k in plain.sets("val")}) < 3
        assert split_parameter_sets(table, (0.7, 0.1, 0.2), seed=seed, stratify=("frequency_hz",)).assignment \
            == sp.assignment
        rec = json.loads(json.dumps(sp.to_dict()))
        assert rec["stratify"] == ["frequency_hz"] and ParameterSplit.from_dict(rec).stratify == ("frequency_hz",)
    assert plain_misses > 0  # the case the option exists for happens with plain draws
    with pytest.raises(ContractError, match="stratify names unknown parameters"):
        split_parameter_sets(table, stratify=("speed_of_light",))


def test_pin_test_sends_the_figure_sets_to_test(frame):
    table = table_from_frame(frame)
    pins = ({"theta_h_min_deg": 10.0, "theta_k_max_deg": -20.0}, {"theta_h_min_deg": -50.0, "theta_k_max_deg": -60.0})
    for seed in range(5):
        sp = split_parameter_sets(table, seed=seed, pin_test=pins)
        tests = [sp.params[k] for k in sp.sets("test")]
        for pin in pins:
            assert any(all(p[k] == v for k, v in pin.items()) for p in tests)
    with pytest.raises(ContractError, match="unknown parameters"):
        split_parameter_sets(table, pin_test=({"theta_q": 1.0},))


def test_normalisation_is_fitted_on_training_runs_only(frame):
    table = table_from_frame(frame)
    sp = split_parameter_sets(table, seed=0)
    train = sp.runs(table, "train", measured_only=False)
    norm = fit_normalisation(table, train)
    rows = np.concatenate([np.arange(table.start[r], table.start[r] + table.length[r]) for r in train])
    assert np.allclose(norm.y_mean, table.y[rows].astype(float).mean(0), rtol=1e-6, atol=1e-9)
    assert np.allclose(norm.x_std, table.x[rows].astype(float).std(0), rtol=1e-5)
    # wild values in validation/test runs do not move it
    y = table.y.copy()
    for r in np.setdiff1d(np.arange(table.n_runs), train):
        y[table.start[r]:table.start[r] + table.length[r]] *= 1000
    import dataclasses

    assert fit_normalisation(dataclasses.replace(table, y=y), train) == norm


def test_several_campaigns_share_parameter_sets(tmp_path):
    a = make_frame(theta_h_min=(10.0, -30.0), theta_k_max=(-20.0, -60.0), speeds=(0.1,), cycles=1.0, campaign_id="a")
    b = make_frame(theta_h_min=(10.0, -50.0), theta_k_max=(-20.0, -60.0), speeds=(0.2,), cycles=1.0, campaign_id="b")
    a.write_parquet(tmp_path / "a.parquet")
    b.drop("alpha_rad").write_parquet(tmp_path / "b.parquet")  # alpha_rad is optional (default 0)
    table = read_table([tmp_path / "a.parquet", tmp_path / "b.parquet"])
    assert table.n_runs == 8 and table.campaigns() == ["a", "b"]
    sp = split_parameter_sets(table, seed=0)
    assert len(sp.assignment) == 6  # (10, -20) and (10, -60) are measured in both campaigns: one set each
    for r in range(table.n_runs):
        assert sp.split_of({c: table.runs[c][r] for c in table.param_columns}) in ("train", "val", "test")


def test_a_folder_stands_for_its_parquet_files(tmp_path, parquet):
    import shutil

    shutil.copy(parquet[0], tmp_path / "one.parquet")
    assert read_table([tmp_path]).n_runs == read_table([parquet[0]]).n_runs
    (tmp_path / "empty").mkdir()
    with pytest.raises(ContractError, match="no .parquet files"):
        read_table([tmp_path / "empty"])
