"""The processed file: explicit schema, provenance metadata, determinism, skip when unchanged, atomicity."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys

import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from ingest_fixtures import RunPlan

from workbench import __version__
from workbench.cli import main
from workbench.contract.columns import TUNNEL_MOTION_PARAMS
from workbench.ingest import (
    IngestSettings,
    ingest_campaign,
    ingest_to_file,
    quality_path,
    read_processed,
    read_provenance,
    write_processed,
)
from workbench.ingest.schema import TOWING_SCHEMA, TUNNEL_SCHEMA


def sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_schema_units_and_run_parameters(campaign, tmp_path):
    root = campaign([RunPlan("r1", form="csv"), RunPlan("r2", form="bin", flow_speed=0.2),
                     RunPlan("r3", form="mcap", flow_speed=0.3)])
    out = write_processed(ingest_campaign(root), tmp_path / "c1.parquet")
    schema = pq.read_schema(out)
    assert schema.remove_metadata().equals(TUNNEL_SCHEMA)
    assert schema.field("time_s").type == pa.float64() and schema.field("interpolated").type == pa.bool_()
    frame = read_processed(out)
    assert frame["interpolated"].sum() == 0
    for p in TUNNEL_MOTION_PARAMS:
        assert p in frame.columns
    by_run = frame.group_by("run_id").agg(pl.col("flow_speed_mps").first(), pl.col("frequency_hz").first(),
                                          pl.col("cycles").first()).sort("run_id")
    assert by_run["flow_speed_mps"].to_list() == [0.1, 0.2, 0.3]
    assert by_run["frequency_hz"].to_list() == [0.5] * 3 and by_run["cycles"].to_list() == [4] * 3


def test_provenance_metadata(campaign, tmp_path):
    root = campaign()
    out = write_processed(ingest_campaign(root, params={"lowpass_cutoff_hz": 5.0}), tmp_path / "c1.parquet")
    meta = read_provenance(out)
    assert meta["workbench_version"] == __version__ and meta["campaign_id"] == "c1"
    assert meta["angle_source"] == "commanded"
    assert meta["params"]["lowpass_cutoff_hz"] == 5.0 and "workers" not in meta["params"]
    expected = {p.relative_to(root).as_posix(): sha(p) for p in root.rglob("*") if p.is_file()}
    assert meta["raw_files"] == expected
    assert meta["skipped_runs"] == [] and meta["quality"]["runs_ingested"] == 2
    assert json.loads(quality_path(out).read_text()) == meta["quality"]


def test_towing_file_schema(campaign, tmp_path):
    root = campaign([RunPlan("t1", flow_speed=0.2, heading="lateral")], facility="towing_tank", name="tow")
    out = write_processed(ingest_campaign(root), tmp_path / "tow.parquet")
    assert pq.read_schema(out).remove_metadata().equals(TOWING_SCHEMA)
    assert read_processed(out)["heading"].unique().to_list() == ["lateral"]


def test_ingest_is_deterministic(campaign, tmp_path):
    root = campaign([RunPlan("r1"), RunPlan("r2", form="bin"), RunPlan("r3", form="mcap")])
    a = write_processed(ingest_campaign(root), tmp_path / "a.parquet")
    b = write_processed(ingest_campaign(root), tmp_path / "b.parquet")
    assert a.read_bytes() == b.read_bytes()


@pytest.mark.slow
def test_worker_threads_do_not_change_the_result(campaign, tmp_path):
    root = campaign([RunPlan(f"r{i}", seed=i) for i in range(6)])
    a = write_processed(ingest_campaign(root, params={"workers": 1}), tmp_path / "a.parquet")
    b = write_processed(ingest_campaign(root, params={"workers": 2}), tmp_path / "b.parquet")
    assert a.read_bytes() == b.read_bytes()


def test_unchanged_inputs_and_params_are_not_reprocessed(campaign, tmp_path, capsys):
    root = campaign()
    out = tmp_path / "c1.parquet"
    assert main(["ingest", str(root), "--out", str(out), "--quiet"]) == 0
    stamp = out.stat().st_mtime_ns
    capsys.readouterr()
    assert main(["ingest", str(root), "--out", str(out)]) == 0
    assert "up to date" in capsys.readouterr().err
    assert out.stat().st_mtime_ns == stamp
    # a changed parameter or a changed raw byte means reprocessing
    assert ingest_to_file(root, out, params={"max_rest_s": 1.0}) is not None
    assert ingest_to_file(root, out, params={"max_rest_s": 1.0}) is None
    path = root / "runs/r1.motion.csv"
    path.write_text(path.read_text().replace("\n", "\r\n"))  # same numbers, other bytes
    assert ingest_to_file(root, out, params={"max_rest_s": 1.0}) is not None
    # the worker count is no result parameter
    assert ingest_to_file(root, out, params=IngestSettings(max_rest_s=1.0, workers=1)) is None


KILLER = r"""
import os, signal, sys
import pyarrow.parquet as pq
from workbench.ingest import ingest_campaign, write_processed
result = ingest_campaign(sys.argv[1])
real = pq.write_table
def write_then_die(table, where, **kw):
    real(table.slice(0, table.num_rows // 3), where, **kw)   # part of the new file is on disk ...
    os.kill(os.getpid(), signal.SIGKILL)                      # ... when the process is killed
pq.write_table = write_then_die
write_processed(result, sys.argv[2])
"""


def test_killed_write_leaves_the_previous_file(campaign, tmp_path):
    root = campaign()
    out = tmp_path / "c1.parquet"
    write_processed(ingest_campaign(root, params={"max_rest_s": 0.5}), out)
    before = out.read_bytes()
    proc = subprocess.run([sys.executable, "-c", KILLER, str(root), str(out)], capture_output=True)
    assert proc.returncode == -9
    assert out.read_bytes() == before
    assert read_processed(out).height > 0
    assert read_provenance(out)["params"]["max_rest_s"] == 0.5


@pytest.mark.slow
def test_killed_ingest_at_random_moments_never_tears_the_file(campaign, tmp_path):
    import random
    import time

    root = campaign([RunPlan(f"r{i}", seed=i) for i in range(4)])
    out = tmp_path / "c1.parquet"
    write_processed(ingest_campaign(root, params={"max_rest_s": 0.5}), out)
    old = out.read_bytes()
    new = None
    rng = random.Random(0)
    for _ in range(6):
        proc = subprocess.Popen([sys.executable, "-m", "workbench.cli", "ingest", str(root), "--out", str(out),
                                 "--quiet", "--force"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                env={**os.environ, "WORKBENCH_HOME": str(tmp_path)})
        time.sleep(rng.uniform(0.5, 3.0))
        proc.kill()
        proc.wait()
        data = out.read_bytes()
        if data != old:
            new = new or data
            assert data == new
        assert read_processed(out).height > 0
