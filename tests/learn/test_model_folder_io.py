"""Reading saved model folders goes through learn's edge (legmodel.py): one-line errors for broken folders.

Folders here are written by the test itself (no training): an ensemble folder without or with a broken
ensemble.json, a model.json of another kind or schema, an MLflow model without the leg_model artifact.
"""

from __future__ import annotations

import json

import pytest
import yaml

from workbench.errors import ModelLoadError


def test_an_ensemble_folder_without_or_with_a_broken_record_is_one_line(tmp_path):
    from workbench.learn.ensemble import SCHEMA, load_ensemble

    with pytest.raises(ModelLoadError, match="not an ensemble folder") as exc:
        load_ensemble(tmp_path)
    assert "\n" not in exc.value.format() and str(tmp_path) in exc.value.format()
    (tmp_path / "ensemble.json").write_text("{not json")
    with pytest.raises(ModelLoadError, match="ensemble.json is not JSON"):
        load_ensemble(tmp_path)
    (tmp_path / "ensemble.json").write_text(json.dumps({"schema": "someone-else@2"}))
    with pytest.raises(ModelLoadError, match="unknown ensemble schema 'someone-else@2'"):
        load_ensemble(tmp_path)
    (tmp_path / "ensemble.json").write_text(json.dumps({"schema": SCHEMA, "members": [{"dir": "member-00"}]}))
    with pytest.raises(ModelLoadError, match="not a trained leg model folder"):
        load_ensemble(tmp_path)


def test_a_path_is_a_learned_model_only_when_its_model_json_says_so(tmp_path):
    from workbench.learn.registry import load_path

    assert load_path(tmp_path) is None  # no model.json
    (tmp_path / "model.json").write_text(json.dumps({"schema": "workbench/augmented-model@1"}))
    assert load_path(tmp_path) is None  # another kind of saved model answers for its own paths
    (tmp_path / "model.json").write_text("[1, 2]")
    assert load_path(tmp_path / "model.json") is None
    (tmp_path / "model.json").write_text(json.dumps({"schema": "workbench/learned-leg-model@99"}))
    with pytest.raises(ModelLoadError, match="unknown model schema 'workbench/learned-leg-model@99'"):
        load_path(tmp_path)


def test_the_model_folder_inside_a_downloaded_mlflow_model(tmp_path):
    from workbench.learn.legmodel import mlflow_model_folder

    assert mlflow_model_folder(tmp_path) == tmp_path  # neither MLmodel nor model.json: the folder itself
    doc = {"flavors": {"python_function": {"artifacts": {"leg_model": {"path": "artifacts/leg_model"}}}}}
    (tmp_path / "MLmodel").write_text(yaml.safe_dump(doc))
    assert mlflow_model_folder(tmp_path) == tmp_path / "artifacts" / "leg_model"
    (tmp_path / "MLmodel").write_text(yaml.safe_dump({"flavors": {"python_function": {}}}))
    with pytest.raises(ModelLoadError, match="without the workbench's leg_model artifact"):
        mlflow_model_folder(tmp_path)


def test_evaluate_with_a_folder_without_model_json_is_one_line_naming_the_folder(parquet, tmp_path, capsys):
    """The CLI's message for a --model folder that holds no trained model: one line, the folder, the fault."""
    from workbench.cli import main
    from workbench.learn.split import split_parameter_sets
    from workbench.learn.windows import read_table

    _, measured = parquet
    split = tmp_path / "split.json"
    split.write_text(json.dumps(split_parameter_sets(read_table([measured])).to_dict()))
    empty = tmp_path / "not-a-model"
    empty.mkdir()
    (empty / "notes.txt").write_text("a folder, but no model.json\n")
    out = tmp_path / "metrics.json"
    rc = main(["evaluate", "--data", str(measured), "--split", str(split), "--out", str(out),
               "--model", str(empty), "--no-mlflow"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and not out.exists()
    assert err == f"error: {empty}: no model.json: not a trained leg model folder", err
