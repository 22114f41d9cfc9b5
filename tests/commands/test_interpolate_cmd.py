"""`workbench interpolate`: a processed tunnel file in, measured + interpolated rows out, provenance kept."""

from __future__ import annotations

import polars as pl
from ingest_fixtures import RunPlan

from workbench.cli import main
from workbench.ingest import read_processed, read_provenance


def test_interpolate_verb(campaign, tmp_path, capsys):
    root = campaign([RunPlan(f"r{i}", flow_speed=v, seed=i) for i, v in enumerate((0.0, 0.1, 0.2, 0.3))])
    processed = tmp_path / "c1.parquet"
    out = tmp_path / "c1-interp.parquet"
    assert main(["ingest", str(root), "--out", str(processed), "--quiet"]) == 0
    assert main(["interpolate", str(processed), "--out", str(out)]) == 0
    assert "interpolated 3 run(s)" in capsys.readouterr().err
    frame = read_processed(out)
    made = frame.filter(pl.col("interpolated"))
    assert sorted(made["run_id"].unique()) == ["r0@v0.050", "r0@v0.150", "r0@v0.250"]
    assert frame.filter(~pl.col("interpolated")).equals(read_processed(processed))
    meta = read_provenance(out)
    assert meta["raw_files"] == read_provenance(processed)["raw_files"]
    assert meta["interpolation"]["sources"]["r0@v0.150"] == ["r0", "r1", "r2", "r3"]
    assert meta["interpolation"]["params"]["speeds_mps"] == [0.05, 0.15, 0.25]


def test_interpolate_refuses_a_towing_file(campaign, tmp_path, capsys):
    root = campaign([RunPlan("t1")], facility="towing_tank", name="tow")
    processed = tmp_path / "tow.parquet"
    assert main(["ingest", str(root), "--out", str(processed), "--quiet"]) == 0
    assert main(["interpolate", str(processed), "--out", str(tmp_path / "x.parquet")]) == 2
    assert "applies to water-tunnel datasets" in capsys.readouterr().err
    assert not (tmp_path / "x.parquet").exists()
