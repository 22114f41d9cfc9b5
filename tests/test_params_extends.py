"""A parameter file's section with ``extends: FILE``: FILE's same section with the variant's keys on top."""

import pytest
import yaml

from workbench.errors import ParamsError
from workbench.gait.config import load_config
from workbench.params import read_section
from workbench.virtual_lab.pool_settings import PoolSettings, model_display_label


def _write(path, doc):
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_nested_keys_merge_and_other_values_replace(tmp_path):
    _write(tmp_path / "base.yaml", {"optimize": {"retain": 4, "nsga2": {"pop_size": 20, "n_gen": 8, "seed": 0},
                                                 "weights": [1.0, 4.0, 2.0]}, "other": {"a": 1}})
    _write(tmp_path / "variant.yaml", {"optimize": {"extends": "base.yaml", "nsga2": {"n_gen": 3},
                                                    "weights": [1.0, 1.0, 1.0]}})
    got, source = read_section(tmp_path / "variant.yaml", "optimize")
    assert got == {"retain": 4, "nsga2": {"pop_size": 20, "n_gen": 3, "seed": 0}, "weights": [1.0, 1.0, 1.0]}
    assert source == str(tmp_path / "variant.yaml")
    assert read_section(tmp_path / "variant.yaml", "optimize.nsga2")[0] == {"pop_size": 20, "n_gen": 3, "seed": 0}
    # a chain of variants, and the base file itself unchanged
    _write(tmp_path / "v2.yaml", {"optimize": {"extends": "variant.yaml", "retain": 2}})
    assert read_section(tmp_path / "v2.yaml", "optimize")[0]["nsga2"]["n_gen"] == 3
    assert read_section(tmp_path / "v2.yaml", "optimize")[0]["retain"] == 2
    assert read_section(tmp_path / "base.yaml", "optimize")[0]["nsga2"]["n_gen"] == 8


def test_a_missing_base_or_section_or_a_loop_is_one_line_naming_the_variant(tmp_path):
    v = _write(tmp_path / "v.yaml", {"optimize": {"extends": "nope.yaml"}})
    with pytest.raises(ParamsError, match=r"v\.yaml, optimize\.extends: the file it extends, nope\.yaml, does not"):
        read_section(v, "optimize")
    _write(tmp_path / "b.yaml", {"train": {}})
    v = _write(tmp_path / "v.yaml", {"optimize": {"extends": "b.yaml"}})
    with pytest.raises(ParamsError, match="b.yaml has no section 'optimize'"):
        read_section(v, "optimize")
    _write(tmp_path / "a.yaml", {"optimize": {"extends": "c.yaml"}})
    _write(tmp_path / "c.yaml", {"optimize": {"extends": "a.yaml"}})
    with pytest.raises(ParamsError, match="loop") as err:
        read_section(tmp_path / "a.yaml", "optimize")
    assert "\n" not in str(err.value)


def test_the_pipelines_variants_are_the_base_files_with_their_changes():
    """pipelines/gait_sides.yaml and trials_sides.yaml: the demo's settings, the per_side_range turn search."""
    base, sides = load_config("pipelines/gait.yaml"), load_config("pipelines/gait_sides.yaml")
    assert base.space.extension == "paper" and sides.space.extension == "per_side_range"
    assert len(sides.space.variables) == 9
    # the task is the trials' turn, exactly the base file's
    assert sides.task("turn") == base.task("turn")
    assert sides.task("turn").spec.cap_s == 60.0 and sides.task("turn").spec.target_yaw_deg == 360.0
    assert sides.simulation == base.simulation and sides.tabulation == base.tabulation
    assert sides.nsga2.seed == base.nsga2.seed and sides.nsga2.pop_size <= base.nsga2.pop_size
    raw = yaml.safe_load(open("pipelines/trials_sides.yaml"))
    pool = PoolSettings.from_mapping(read_section("pipelines/trials_sides.yaml", "pool")[0])
    assert pool.tasks == ("turn",) and pool.models == tuple(raw["pool"]["models"])
    assert pool.fps == PoolSettings.from_mapping(read_section("pipelines/trials.yaml", "pool")[0]).fps
    assert [model_display_label(m, pool.model_labels) for m in pool.models] == ["EF-sides", "FED-LSTM-sides"]


def test_a_typo_in_a_variant_names_the_variant_file(tmp_path):
    v = _write(tmp_path / "gait_x.yaml", {"optimize": {"extends": str((tmp_path / "g.yaml").resolve()),
                                                       "nsga2": {"pop_sise": 3}}})
    _write(tmp_path / "g.yaml", {"optimize": {"nsga2": {"pop_size": 4}}})
    with pytest.raises(ParamsError, match=r"gait_x\.yaml, optimize\.nsga2\.pop_sise: unknown setting") as err:
        load_config(v)
    assert "\n" not in str(err.value)
