"""`workbench campaign validate|add|list` with a real git + DVC repository in tmp_path."""

from __future__ import annotations

import subprocess
import sys

import pytest
import yaml
from ingest_fixtures import RunPlan, tree_hash, write_campaign

from workbench.cli import main
from workbench.ingest.registry import load_registry


def test_validate_lists_every_violation(campaign, capsys):
    root = campaign([RunPlan("r1"), RunPlan("r2"), RunPlan("r3")])
    (root / "runs/r1.loadcell.csv").write_bytes(b"")
    path = root / "runs/r1.motion.csv"
    path.write_text(path.read_text().replace("time_s,hfe_cmd_deg", "t,hfe_cmd_deg", 1))
    lines = (root / "runs/r3.loadcell.csv").read_text().splitlines(keepends=True)
    (root / "runs/r3.loadcell.csv").write_text("".join(lines[:700] + lines[800:]))
    manifest = root / "campaign.toml"
    manifest.write_text(manifest.read_text().replace('flow_speed_mps = 0.1\n', 'flow_speed_mps = -0.1\n', 1))
    before = tree_hash(root)
    assert main(["campaign", "validate", str(root)]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("error:")]
    assert len(err) == 4, err
    assert "run r1" in err[0] and "flow_speed_mps must be a non-negative number" in err[0]
    assert any("r1.loadcell.csv" in e and "empty file" in e for e in err)
    assert any("r1.motion.csv" in e and "missing column(s) time_s" in e and "line 1" in e for e in err)
    assert any("r3.loadcell.csv" in e and "line 701" in e and "gap" in e for e in err)
    assert tree_hash(root) == before


def test_validate_a_good_campaign(campaign, capsys):
    root = campaign([RunPlan("r1", form="bin"), RunPlan("r2", form="mcap")])
    assert main(["campaign", "validate", str(root)]) == 0
    assert "valid (water_tunnel, 2 runs checked)" in capsys.readouterr().err


def test_validate_warns_about_saturation(campaign, capsys):
    root = campaign([RunPlan("r1")], full_scale=(5.0, 0.25, 5.0, 1.0, 1.0, 1.0))
    assert main(["campaign", "validate", str(root)]) == 0
    assert "warning: run r1: readings at full scale in fy_n" in capsys.readouterr().err


@pytest.fixture
def project(tmp_path, monkeypatch):
    """A fresh git + DVC project with the registry file, as the workbench repository has."""
    root = tmp_path / "proj"
    (root / "datasets" / "raw").mkdir(parents=True)
    (root / "pipelines").mkdir()
    (root / "pipelines" / "campaigns.yaml").write_text("tunnel:\n  - demo-tunnel\ntowing: []\n")
    subprocess.run(["git", "init", "-q"], cwd=root, check=True)
    subprocess.run([sys.executable, "-m", "dvc", "init", "-q"], cwd=root, check=True)
    monkeypatch.setenv("WORKBENCH_HOME", str(root))
    return root


@pytest.mark.slow
def test_add_validates_registers_and_tracks_with_dvc(project, capsys):
    root = write_campaign(project / "datasets/raw/tunnel-2025-03", [RunPlan("r1"), RunPlan("r2")])
    before = tree_hash(root)
    assert main(["campaign", "add", str(root)]) == 0
    err = capsys.readouterr().err
    assert "registered tunnel-2025-03" in err and "tracked with DVC" in err
    assert load_registry(project)["tunnel"] == ["demo-tunnel", "tunnel-2025-03"]
    dvc_file = project / "datasets/raw/tunnel-2025-03.dvc"
    assert yaml.safe_load(dvc_file.read_text())["outs"][0]["path"] == "tunnel-2025-03"
    assert "/tunnel-2025-03" in (project / "datasets/raw/.gitignore").read_text()
    assert tree_hash(root) == before
    # again: nothing changes
    assert main(["campaign", "add", str(root)]) == 0
    err = capsys.readouterr().err
    assert "already registered" in err and "already tracked by DVC" in err
    assert load_registry(project)["tunnel"] == ["demo-tunnel", "tunnel-2025-03"]
    # and list shows it
    assert main(["campaign", "list"]) == 0
    out = capsys.readouterr().out
    assert "tunnel-2025-03" in out and "dvc add" in out and "folder missing" in out  # demo-tunnel not generated


def test_add_refuses_an_invalid_campaign(project, capsys):
    root = write_campaign(project / "datasets/raw/bad-one", [RunPlan("r1")])
    (root / "runs/r1.motion.csv").write_bytes(b"")
    assert main(["campaign", "add", str(root)]) == 2
    assert "not added" in capsys.readouterr().err
    assert load_registry(project)["tunnel"] == ["demo-tunnel"]
    assert not (project / "datasets/raw/bad-one.dvc").exists()


def test_add_refuses_a_folder_outside_datasets_raw(project, tmp_path, capsys):
    root = write_campaign(tmp_path / "elsewhere" / "c9", [RunPlan("r1")])
    assert main(["campaign", "add", str(root)]) == 2
    assert "copy it to datasets/raw/c9" in capsys.readouterr().err


def test_add_does_not_dvc_add_a_stage_output(project, capsys):
    (project / "dvc.yaml").write_text(yaml.safe_dump({"stages": {"virtual_lab_tunnel": {
        "cmd": "workbench virtual-lab tunnel datasets/raw/demo-tunnel", "outs": ["datasets/raw/demo-tunnel"]}}}))
    root = write_campaign(project / "datasets/raw/demo-tunnel", [RunPlan("r1")])
    towing = write_campaign(project / "datasets/raw/demo-towing", [RunPlan("t1")], facility="towing_tank")
    assert main(["campaign", "add", str(root)]) == 0
    err = capsys.readouterr().err
    assert "already registered" in err and "output of stage 'virtual_lab_tunnel'" in err
    assert main(["campaign", "add", str(towing), "--no-dvc"]) == 0
    assert load_registry(project) == {"tunnel": ["demo-tunnel"], "towing": ["demo-towing"]}
    assert not list((project / "datasets/raw").glob("*.dvc"))


@pytest.mark.slow
def test_add_completes_after_a_dvc_add_killed_mid_write(project, capsys):
    """DVC rewrites `.dvc/tmp/rwlock` and the campaign's .dvc file in place (open, then write): a `dvc add`
    killed in between leaves them empty (the CI failure of stop 25: "Unable to read RWLock-file")."""
    root = write_campaign(project / "datasets/raw/tunnel-cut", [RunPlan("r1"), RunPlan("r2")])
    before = tree_hash(root)
    (project / ".dvc/tmp").mkdir(exist_ok=True)
    (project / ".dvc/tmp/rwlock").write_text("")  # what a kill between open and write leaves
    (project / "datasets/raw/tunnel-cut.dvc").write_text("")
    assert main(["campaign", "add", str(root)]) == 0
    err = capsys.readouterr().err
    assert "DVC's lock record was cut" in err and "running dvc add again" in err and "tracked with DVC" in err
    assert yaml.safe_load((project / "datasets/raw/tunnel-cut.dvc").read_text())["outs"][0]["path"] == "tunnel-cut"
    aside = list((project / ".dvc/tmp").glob("rwlock.cut-*"))
    assert len(aside) == 1 and aside[0].read_text() == ""  # kept, not deleted
    assert tree_hash(root) == before
    st = subprocess.run([sys.executable, "-m", "dvc", "status", "--json"], cwd=project, capture_output=True, text=True)
    assert st.returncode == 0 and st.stdout.strip() in ("{}", ""), st.stdout + st.stderr


def test_add_refuses_a_dvc_file_that_is_not_its_own(project, capsys):
    root = write_campaign(project / "datasets/raw/tunnel-x", [RunPlan("r1")])
    dvc_file = project / "datasets/raw/tunnel-x.dvc"
    dvc_file.write_text("outs:\n- md5: abc\n  si")
    assert main(["campaign", "add", str(root)]) == 2
    err = capsys.readouterr().err
    assert "tunnel-x.dvc" in err and "not valid YAML" in err
    dvc_file.write_text("outs:\n- path: other\n")
    assert main(["campaign", "add", str(root)]) == 2
    assert "does not track the folder tunnel-x" in capsys.readouterr().err
    assert load_registry(project)["tunnel"] == ["demo-tunnel"]  # refused before registering
    assert dvc_file.read_text() == "outs:\n- path: other\n"
