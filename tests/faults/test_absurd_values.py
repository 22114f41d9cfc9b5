"""Absurd values are refused by `campaign validate` and `ingest` with the file, run, field or column, line.

Each campaign is a copy of a small fixture campaign with one fault planted by a formula written
here; the raw folder must come out untouched and no output may be written.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from ingest_fixtures import RunPlan, tree_hash, write_campaign

from workbench.cli import main

pytestmark = pytest.mark.faults


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    return write_campaign(tmp_path_factory.mktemp("base") / "base", [RunPlan("r1"), RunPlan("r2", flow_speed=0.2)])


@pytest.fixture(scope="module")
def base_towing(tmp_path_factory):
    return write_campaign(tmp_path_factory.mktemp("base") / "tow", [RunPlan("t1", flow_speed=0.2)],
                          facility="towing_tank")


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    toml = dst / "campaign.toml"
    toml.write_text(toml.read_text().replace(f'id = "{src.name}"', f'id = "{dst.name}"'))
    return dst


def _manifest(old: str, new: str):
    def plant(root: Path):
        t = (root / "campaign.toml").read_text()
        assert old in t
        (root / "campaign.toml").write_text(t.replace(old, new, 1))
    return plant


def _cell(file: str, column: str, line: int, value: str):
    """Replace one cell: data line ``line`` of the file (line 1 is the header)."""
    def plant(root: Path):
        p = root / "runs" / file
        lines = p.read_text().splitlines()
        cells = lines[line - 1].split(",")
        cells[lines[0].split(",").index(column)] = value
        lines[line - 1] = ",".join(cells)
        p.write_text("\n".join(lines) + "\n")
    return plant


#: name -> (fault planted, what the one-line message must name)
TUNNEL_CASES = {
    "cycles-3e9": (_manifest("cycles = 4", "cycles = 3000000000"), ["campaign.toml", "run r1", "field cycles"]),
    "cycles-1e5": (_manifest("cycles = 4", "cycles = 100000"), ["run r1", "field cycles", "implausible"]),
    "speed-1e300": (_manifest("flow_speed_mps = 0.1", "flow_speed_mps = 1e300"),
                    ["run r1", "field flow_speed_mps", "implausible"]),
    "frequency-1e300": (_manifest("frequency_hz = 0.5", "frequency_hz = 1e300"),
                        ["run r1", "field frequency_hz", "implausible"]),
    "angle-1e300": (_manifest("theta_k_max_deg = -20.0", "theta_k_max_deg = 1e300"),
                    ["run r1", "field theta_k_max_deg", "implausible"]),
    "phase-1e300": (_manifest("phi_rad = 1.0472", "phi_rad = -1e300"), ["run r1", "field phi_rad"]),
    "rate-1e300": (_manifest("rate_hz = 500.0", "rate_hz = 1e300"), ["[loadcell] rate_hz", "implausible"]),
    "inf-cell": (_cell("r1.loadcell.csv", "fy_n", 50, "inf"),
                 ["r1.loadcell.csv", "run r1", "line 50", "infinite value", "fy_n"]),
    "minus-inf-cell": (_cell("r2.loadcell.csv", "tz_nm", 77, "-inf"),
                       ["r2.loadcell.csv", "run r2", "line 77", "infinite value", "tz_nm"]),
    "1e308-cell": (_cell("r1.loadcell.csv", "fx_n", 70, "1e308"),
                   ["r1.loadcell.csv", "run r1", "line 70", "fx_n = 1e+308", "full scale"]),
    "angle-cell-1e300": (_cell("r2.motion.csv", "kfe_cmd_deg", 30, "1e300"),
                         ["r2.motion.csv", "run r2", "line 30", "kfe_cmd_deg"]),
}
TOWING_CASES = {
    "towing-speed-1e300": (_manifest("flow_speed_mps = 0.2", "flow_speed_mps = 1e300"),
                           ["run t1", "field flow_speed_mps"]),
    "carriage-1e300": (_cell("t1.carriage.csv", "position_m", 40, "1e300"),
                       ["t1.carriage.csv", "run t1", "line 40", "position_m"]),
}


def _refused_by_both(root: Path, tmp_path: Path, capsys, must_name: list[str]) -> None:
    before = tree_hash(root)
    out = tmp_path / "out" / f"{root.name}.parquet"
    assert main(["campaign", "validate", str(root)]) == 2
    validate = capsys.readouterr()
    assert main(["ingest", str(root), "--out", str(out), "--quiet"]) == 2
    ingest_err = capsys.readouterr().err
    errors = [ln for ln in (validate.out + validate.err + ingest_err).splitlines() if ln.startswith("error: ")]
    assert len(errors) >= 2
    for line in errors:
        assert "Traceback" not in line
        assert "(" in line and ")" in line, f"no hint on what to do: {line}"
    for text in (validate.out + validate.err, ingest_err):
        for word in must_name:
            assert word in text, f"{word!r} missing from: {text}"
    assert tree_hash(root) == before
    assert not out.exists() and not (out.parent.exists() and any(out.parent.iterdir()))


@pytest.mark.parametrize("case", list(TUNNEL_CASES))
def test_absurd_tunnel_campaign_is_refused(case, base, tmp_path, capsys):
    plant, must_name = TUNNEL_CASES[case]
    root = _copy(base, tmp_path / "raw" / case)
    plant(root)
    _refused_by_both(root, tmp_path, capsys, must_name)


@pytest.mark.parametrize("case", list(TOWING_CASES))
def test_absurd_towing_campaign_is_refused(case, base_towing, tmp_path, capsys):
    plant, must_name = TOWING_CASES[case]
    root = _copy(base_towing, tmp_path / "raw" / case)
    plant(root)
    _refused_by_both(root, tmp_path, capsys, must_name)


def test_a_rig_that_really_goes_further_raises_the_limit_in_the_params(base, tmp_path, capsys):
    root = _copy(base, tmp_path / "raw" / "fast")
    _manifest("flow_speed_mps = 0.1", "flow_speed_mps = 3.5")(root)
    out = tmp_path / "fast.parquet"
    assert main(["ingest", str(root), "--out", str(out), "--quiet"]) == 2
    assert "ingest.limits.flow_speed_mps_max" in capsys.readouterr().err
    params = tmp_path / "ingest.yaml"
    params.write_text("ingest:\n  limits:\n    flow_speed_mps_max: 4.0\n")
    assert main(["ingest", str(root), "--out", str(out), "--quiet", "--params", str(params)]) == 0
    assert out.is_file()
    params.write_text("ingest:\n  limits:\n    flow_speed_max: 4.0\n")
    assert main(["ingest", str(root), "--out", str(out), "--quiet", "--params", str(params)]) == 2
    assert "ingest.limits.flow_speed_max: unknown setting 'flow_speed_max' (did you mean 'flow_speed_mps_max'?" \
        in capsys.readouterr().err


def test_a_bom_in_campaign_toml_is_accepted(base, tmp_path, capsys):
    root = _copy(base, tmp_path / "raw" / "bom")
    (root / "campaign.toml").write_bytes(b"\xef\xbb\xbf" + (root / "campaign.toml").read_bytes())
    assert main(["campaign", "validate", str(root)]) == 0
    assert main(["ingest", str(root), "--out", str(tmp_path / "bom.parquet"), "--quiet"]) == 0


def test_a_manifest_in_another_encoding_says_so(base, tmp_path, capsys):
    root = _copy(base, tmp_path / "raw" / "latin")
    t = (root / "campaign.toml").read_text().replace('description = "test fixture"', 'description = "Düse"')
    (root / "campaign.toml").write_bytes(t.encode("latin-1"))
    assert main(["campaign", "validate", str(root)]) == 2
    out = capsys.readouterr()
    assert "not UTF-8 text" in out.out + out.err and "save campaign.toml as UTF-8" in out.out + out.err


def test_a_zero_byte_video_says_empty_file(tmp_path):
    from workbench.errors import DataError
    from workbench.trials.video import _open

    video = tmp_path / "t.mp4"
    video.write_bytes(b"")
    with pytest.raises(DataError, match="empty file"):
        _open(video)
