"""Section 5 of the foundation issue: each kind of bad input gives one clear line, exit status 2,
no output written, and the raw folder untouched (hashed before and after)."""

from __future__ import annotations

import json

import numpy as np
import polars as pl
import pytest
from ingest_fixtures import RunPlan, tree_hash

from workbench.cli import main
from workbench.ingest import quality_path, read_provenance


def refused(capsys, tmp_path, root, *fragments):
    """Run `workbench ingest`; assert the refusal contract; return the error line."""
    out = tmp_path / "processed" / "out.parquet"
    before = tree_hash(root)
    rc = main(["ingest", str(root), "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, err
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for f in fragments:
        assert f in lines[0], lines[0]
    assert not out.exists() and not quality_path(out).exists()
    assert not list(out.parent.glob("*")) if out.parent.exists() else True
    assert tree_hash(root) == before
    return lines[0]


def edit_csv(path, fn):
    df = pl.read_csv(path)
    fn(df).write_csv(path, float_precision=None)


def edit_lines(path, fn):
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(fn(lines)))


def test_missing_column(campaign, capsys, tmp_path):
    root = campaign()
    edit_csv(root / "runs/r2.loadcell.csv", lambda df: df.drop("tz_nm"))
    refused(capsys, tmp_path, root, "runs/r2.loadcell.csv", "run r2", "line 1", "missing column(s) tz_nm")


def test_extra_column(campaign, capsys, tmp_path):
    root = campaign()
    edit_csv(root / "runs/r2.motion.csv", lambda df: df.with_columns(pl.lit(20.0).alias("water_temp_c")))
    refused(capsys, tmp_path, root, "runs/r2.motion.csv", "run r2", "unexpected column(s) water_temp_c")


def test_measured_angle_columns_without_feedback_get_a_hint(campaign, capsys, tmp_path):
    root = campaign()
    edit_csv(root / "runs/r1.motion.csv", lambda df: df.with_columns(
        pl.col("hfe_cmd_deg").alias("hfe_meas_deg"), pl.col("kfe_cmd_deg").alias("kfe_meas_deg")))
    refused(capsys, tmp_path, root, "run r1", "unexpected column(s) hfe_meas_deg, kfe_meas_deg", "[motion] feedback")


def test_non_numeric_cell(campaign, capsys, tmp_path):
    root = campaign()

    def corrupt(lines):
        cells = lines[49].split(",")
        cells[2] = "0.1O3"  # a letter O typed for a zero
        lines[49] = ",".join(cells)
        return lines
    edit_lines(root / "runs/r2.loadcell.csv", corrupt)
    refused(capsys, tmp_path, root, "runs/r2.loadcell.csv", "run r2", "line 50", "non-numeric value '0.1O3'", "fy_n")


def test_nan_stretch_is_refused(campaign, capsys, tmp_path):
    root = campaign()

    def nan_rows(df):
        idx = pl.int_range(pl.len())
        return df.with_columns(pl.when((idx >= 300) & (idx < 340)).then(float("nan")).otherwise(pl.col("fz_n"))
                               .alias("fz_n"))
    edit_csv(root / "runs/r1.loadcell.csv", nan_rows)
    refused(capsys, tmp_path, root, "runs/r1.loadcell.csv", "run r1", "line 302", "NaN stretch of 40 samples in fz_n")


def test_short_nan_runs_are_bridged_and_flagged(campaign, tmp_path):
    root = campaign()

    def two_nans(lines):
        for i in (200, 201, 900):
            cells = lines[i].split(",")
            cells[1] = ""  # empty cells are missing values too
            lines[i] = ",".join(cells)
        return lines
    edit_lines(root / "runs/r1.loadcell.csv", two_nans)
    out = tmp_path / "out.parquet"
    assert main(["ingest", str(root), "--out", str(out), "--quiet"]) == 0
    q = json.loads(quality_path(out).read_text())["runs"][0]
    assert q["nan_filled"] == 3 and "nan_filled" in q["flags"]


def test_non_monotonic_timestamps(campaign, capsys, tmp_path):
    root = campaign()

    def swap(lines):
        lines[100], lines[101] = lines[101], lines[100]
        return lines
    edit_lines(root / "runs/r2.motion.csv", swap)
    refused(capsys, tmp_path, root, "runs/r2.motion.csv", "run r2", "line 102", "non-monotonic timestamps")


def test_duplicated_timestamps(campaign, capsys, tmp_path):
    root = campaign()
    edit_lines(root / "runs/r1.loadcell.csv", lambda lines: lines[:500] + [lines[499]] + lines[500:])
    refused(capsys, tmp_path, root, "runs/r1.loadcell.csv", "run r1", "line 501", "duplicated timestamp")


def test_gap(campaign, capsys, tmp_path):
    root = campaign()
    edit_lines(root / "runs/r2.loadcell.csv", lambda lines: lines[:1000] + lines[1100:])
    line = refused(capsys, tmp_path, root, "runs/r2.loadcell.csv", "run r2", "line 1001", "gap of 0.202 s")
    assert "limit 0.050 s" in line


def test_missing_trigger_edge(campaign, capsys, tmp_path):
    root = campaign()

    def drop_pulse(df):
        # the load cell misses the third pulse (its line input stuck low for a moment)
        t = df["time_s"].to_numpy()
        sync = df["sync"].to_numpy().copy()
        edges = np.flatnonzero(np.diff(sync) == 1) + 1
        sync[edges[2]:edges[2] + 60] = 0
        return df.with_columns(pl.Series("sync", sync)).with_columns(pl.Series("time_s", t))
    edit_csv(root / "runs/r2.loadcell.csv", drop_pulse)
    refused(capsys, tmp_path, root, "runs/r2.loadcell.csv", "run r2", "missing trigger edge")


def test_no_trigger_edges_at_all(campaign, capsys, tmp_path):
    root = campaign()
    edit_csv(root / "runs/r1.loadcell.csv", lambda df: df.with_columns(pl.lit(0).alias("sync")))
    refused(capsys, tmp_path, root, "runs/r1.loadcell.csv", "run r1", "no rising trigger edge")


def test_log_starting_inside_the_pulse_train_is_ambiguous(campaign, capsys, tmp_path):
    root = campaign([RunPlan("r1"), RunPlan("r2", lc_lead_s=-3.0)])  # load cell starts 1.4 s into the run
    refused(capsys, tmp_path, root, "runs/r2.loadcell.csv", "run r2", "which trigger pulse is the run's first")


def test_empty_file(campaign, capsys, tmp_path):
    root = campaign()
    (root / "runs/r2.motion.csv").write_bytes(b"")
    refused(capsys, tmp_path, root, "runs/r2.motion.csv", "run r2", "empty file")


def test_header_only_file(campaign, capsys, tmp_path):
    root = campaign()
    (root / "runs/r2.motion.csv").write_text("time_s,hfe_cmd_deg,kfe_cmd_deg,sync\n")
    refused(capsys, tmp_path, root, "runs/r2.motion.csv", "run r2", "no data rows")


def test_truncated_file(campaign, capsys, tmp_path):
    root = campaign()
    path = root / "runs/r1.loadcell.csv"
    data = path.read_bytes()
    cut = data.rfind(b",", 0, len(data) // 2)  # stop mid-line, like an interrupted copy
    path.write_bytes(data[:cut])
    refused(capsys, tmp_path, root, "runs/r1.loadcell.csv", "run r1", "truncated file", "fields")


def test_ragged_line_inside_file(campaign, capsys, tmp_path):
    root = campaign()

    def cut(lines):
        lines[300] = ",".join(lines[300].split(",")[:5]) + "\n"
        return lines
    edit_lines(root / "runs/r1.loadcell.csv", cut)
    refused(capsys, tmp_path, root, "run r1", "line 301", "5 fields, expected 8")


@pytest.mark.parametrize("damage", ["truncate", "garbage", "flip"])
def test_corrupt_mcap(campaign, capsys, tmp_path, damage):
    root = campaign([RunPlan("r1", form="mcap"), RunPlan("r2", form="mcap")])
    path = root / "runs/r2.mcap"
    data = bytearray(path.read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 2]
    elif damage == "garbage":
        data = bytearray(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    else:
        data[40:2000] = bytes(1960)
    path.write_bytes(bytes(data))
    line = refused(capsys, tmp_path, root, "runs/r2.mcap", "run r2")
    assert "corrupt MCAP" in line or "no messages on" in line


def test_mcap_missing_topic(campaign, capsys, tmp_path):
    from ingest_fixtures import write_mcap

    root = campaign([RunPlan("r1", form="mcap")])
    write_mcap(root / "runs/r1.mcap", {"time_s": [0.0, 0.002, 0.004], **{c: [0.0] * 3 for c in
               ("fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm")}, "sync": [0, 0, 0]},
               {"time_s": [], "hfe_cmd_deg": [], "kfe_cmd_deg": [], "sync": []}, "water_tunnel")
    refused(capsys, tmp_path, root, "runs/r1.mcap", "run r1", "no messages on /leg/joint_command")


def test_bin_with_no_valid_frames(campaign, capsys, tmp_path):
    root = campaign([RunPlan("r1", form="bin"), RunPlan("r2", form="bin")])
    path = root / "runs/r1.loadcell.bin"
    path.write_bytes(np.random.default_rng(1).integers(0, 256, 40000, dtype=np.uint8).tobytes().replace(b"\xaa\x55", b"\xaa\x56"))
    refused(capsys, tmp_path, root, "runs/r1.loadcell.bin", "run r1", "no valid frames in 40000 bytes")


def test_path_escaping_the_campaign_folder(campaign, capsys, tmp_path):
    root = campaign()
    (tmp_path / "raw" / "outside.csv").write_text("time_s\n")
    manifest = root / "campaign.toml"
    manifest.write_text(manifest.read_text().replace('loadcell = "runs/r2.loadcell.csv"',
                                                     'loadcell = "../outside.csv"'))
    refused(capsys, tmp_path, root, "campaign.toml", "run r2", "field loadcell", "escapes the campaign folder")


def test_duplicate_run_ids(campaign, capsys, tmp_path):
    root = campaign()
    manifest = root / "campaign.toml"
    text = manifest.read_text()
    block = text[text.index("[[runs]]", text.index('id = "r2"') - 20):]
    manifest.write_text(text + "\n" + block.replace('id = "r2"', 'id = "r1"'))
    refused(capsys, tmp_path, root, "campaign.toml", "run r1", "duplicate run id")


def test_unknown_schema_version(campaign, capsys, tmp_path):
    root = campaign(schema="workbench/campaign@2")
    refused(capsys, tmp_path, root, "campaign.toml", "field schema", "unknown schema version 'workbench/campaign@2'")


def test_missing_file(campaign, capsys, tmp_path):
    root = campaign()
    (root / "runs/r2.motion.csv").unlink()
    refused(capsys, tmp_path, root, "runs/r2.motion.csv", "run r2", "file not found")


def test_sync_values_other_than_0_1(campaign, capsys, tmp_path):
    root = campaign()
    edit_csv(root / "runs/r1.motion.csv", lambda df: df.with_columns((pl.col("sync") * 5).alias("sync")))
    refused(capsys, tmp_path, root, "runs/r1.motion.csv", "run r1", "sync must be 0 or 1")


def test_full_scale_readings_are_flagged_not_refused(campaign, tmp_path, capsys):
    root = campaign(full_scale=(5.0, 0.25, 5.0, 1.0, 1.0, 1.0))  # fy swings to about +-0.3 N
    out = tmp_path / "out.parquet"
    assert main(["ingest", str(root), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "saturated fy_n" in err
    q = json.loads(quality_path(out).read_text())
    assert q["runs_saturated"] == ["r1", "r2"]
    run = q["runs"][0]
    assert run["saturated"] and set(run["saturated_samples"]) == {"fy_n"} and run["saturated_samples"]["fy_n"] > 100


def _break_runs(root, ids):
    for rid in ids:
        edit_lines(root / f"runs/{rid}.loadcell.csv", lambda lines: lines[:1000] + lines[1100:])


def test_campaign_with_bad_runs_is_refused_listing_every_bad_run(campaign, capsys, tmp_path):
    root = campaign([RunPlan(f"r{i}") for i in range(1, 5)])
    _break_runs(root, ["r2", "r4"])
    line = refused(capsys, tmp_path, root, "campaign.toml", "2 bad run(s): r2, r4", "--skip-bad-runs")
    assert "runs/r2.loadcell.csv" in line


def test_skip_bad_runs_ingests_the_rest_and_records_what_was_left_out(campaign, capsys, tmp_path):
    root = campaign([RunPlan(f"r{i}") for i in range(1, 5)])
    _break_runs(root, ["r2", "r4"])
    before = tree_hash(root)
    out = tmp_path / "out.parquet"
    assert main(["ingest", str(root), "--out", str(out), "--skip-bad-runs"]) == 0
    err = capsys.readouterr().err
    assert "left out:" in err and "run r2" in err and "run r4" in err
    meta = read_provenance(out)
    assert [s["run_id"] for s in meta["skipped_runs"]] == ["r2", "r4"]
    assert all("gap" in s["error"] for s in meta["skipped_runs"])
    q = json.loads(quality_path(out).read_text())
    assert [r["status"] for r in q["runs"]] == ["ok", "skipped", "ok", "skipped"]
    assert q["runs_skipped"] == 2
    assert sorted(pl.read_parquet(out)["run_id"].unique()) == ["r1", "r3"]
    assert tree_hash(root) == before


def test_skip_bad_runs_with_no_good_run_still_refuses(campaign, capsys, tmp_path):
    root = campaign([RunPlan("r1")])
    _break_runs(root, ["r1"])
    out = tmp_path / "out.parquet"
    assert main(["ingest", str(root), "--out", str(out), "--skip-bad-runs"]) == 2
    assert not out.exists()


@pytest.mark.slow
def test_bad_runs_found_on_worker_threads_keep_their_run_and_line(campaign):
    from workbench.errors import CampaignRefused
    from workbench.ingest import ingest_campaign

    root = campaign([RunPlan(f"r{i}", seed=i) for i in range(1, 5)])
    _break_runs(root, ["r3"])
    with pytest.raises(CampaignRefused) as info:
        ingest_campaign(root, params={"workers": 2})
    (err,) = info.value.errors
    assert err.run == "r3" and err.where == "line 1001" and "gap" in err.fault
