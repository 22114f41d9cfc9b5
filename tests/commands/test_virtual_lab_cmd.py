"""``workbench virtual-lab``: help with examples, effects listing, YAML parameters, one-line errors."""

import json

import yaml

from workbench.cli import main
from workbench.contract.campaign import check_manifest
from workbench.virtual_lab.effects import REGISTRY


def test_help_and_effects(capsys):
    assert main(["virtual-lab"]) == 0
    out = capsys.readouterr().out
    assert "tunnel" in out and "towing" in out and "examples:" in out
    assert main(["virtual-lab", "effects"]) == 0
    out = capsys.readouterr().out
    for name in REGISTRY:
        assert name in out
    assert main(["virtual-lab", "effects", "--json"]) == 0
    assert {e["name"] for e in json.loads(capsys.readouterr().out)} == set(REGISTRY)


def test_tunnel_from_params_with_flag_overrides(tmp_path, capsys):
    params = tmp_path / "vl.yaml"
    params.write_text(yaml.safe_dump({"tunnel": {
        "seed": 3, "form": "csv", "flow_speeds_mps": [0.1], "cycles": 1,
        "grid": {"theta_h_min_deg": [10.0], "theta_k_max_deg": [-20.0], "frequency_hz": [0.6], "phi_rad": [1.0]},
        "effects": ["servo_lag:tau_s=0.03"],
        "loadcell": {"rate_hz": 250.0}, "motion": {"rest_after_s": 0.3}, "physics": {"c_n90": 1.1},
    }}))
    out = tmp_path / "cli-tunnel"
    rc = main(["virtual-lab", "tunnel", str(out), "--params", str(params), "--seed", "7", "--form", "mcap",
               "--effect", "lift:cl=0.2"])
    assert rc == 0
    camp, errors = check_manifest(out)
    assert errors == [] and len(camp.runs) == 1 and camp.runs[0].mcap is not None
    assert camp.loadcell.rate_hz == 250.0
    truth = json.loads((out / "truth.json").read_text())
    assert truth["seed"] == 7 and truth["form"] == "mcap"
    assert [e["name"] for e in truth["effects"]] == ["servo_lag", "lift"]
    assert truth["truth"]["params"]["c_n90"] == 1.1
    assert "wrote" in capsys.readouterr().err


def test_towing_cli(tmp_path):
    out = tmp_path / "cli-tow"
    assert main(["virtual-lab", "towing", str(out), "--speeds", "0.2", "--seed", "1"]) == 0
    camp, errors = check_manifest(out)
    assert errors == [] and [r.heading for r in camp.runs] == ["forward", "lateral"]


def test_bad_input_is_one_line_and_status_2(tmp_path, capsys):
    assert main(["virtual-lab", "tunnel", str(tmp_path / "x"), "--effect", "warp_drive:c=9"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "warp_drive" in err and "\n" not in err
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"tunnel": {"loadcell": {"rate": 5}}}))
    assert main(["virtual-lab", "tunnel", str(tmp_path / "y"), "--params", str(bad)]) == 2
    assert "unknown setting 'rate'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists()
