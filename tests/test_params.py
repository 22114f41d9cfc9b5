"""workbench.params: one loader for pipeline YAML sections, on real YAML files written here."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Optional

import pytest
import yaml

from workbench.cli import main
from workbench.errors import ParamsError, WorkbenchError
from workbench.hydro.drag import DragFitSettings, PlateauSettings
from workbench.ingest.params import IngestSettings
from workbench.params import build, load_settings, read_section

REPO = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Inner:
    """A nested settings block."""

    gain: float = 1.0
    taps: tuple[int, ...] = (1, 2)


@dataclass(frozen=True)
class DemoSettings:
    """Every field form the loader supports."""

    rate_hz: float = 10.0
    count: int = 3
    enabled: bool = True
    cutoff_hz: Optional[float] = 2.0  # noqa: UP045 (the typing spelling must work too)
    label: str | None = None
    mode: Literal["fast", "exact"] = "fast"
    window_s: tuple[float, float] = (0.5, 1.5)
    names: list[str] = field(default_factory=list)
    extra: dict[str, float] = field(default_factory=dict)
    inner: Inner = field(default_factory=Inner)

    def __post_init__(self):
        if self.count < 0:
            raise ValueError("count must not be negative")


def _yaml(path, doc) -> str:
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return str(path)


def test_a_full_section_is_coerced_into_nested_frozen_settings(tmp_path):
    f = _yaml(tmp_path / "p.yaml", {"demo": {
        "rate_hz": 65, "count": 4, "enabled": False, "cutoff_hz": None, "label": "x", "mode": "exact",
        "window_s": [1, 2], "names": ["a", "b"], "extra": {"k": 3}, "inner": {"gain": 2, "taps": [3, 4, 5]}}})
    s = load_settings(DemoSettings, f, "demo")
    assert s == DemoSettings(rate_hz=65.0, count=4, enabled=False, cutoff_hz=None, label="x", mode="exact",
                             window_s=(1.0, 2.0), names=["a", "b"], extra={"k": 3.0},
                             inner=Inner(gain=2.0, taps=(3, 4, 5)))
    assert isinstance(s.rate_hz, float) and isinstance(s.inner.gain, float) and isinstance(s.window_s, tuple)
    with pytest.raises(AttributeError):
        s.rate_hz = 1.0  # frozen
    # what is not given keeps its default, also inside a nested block
    part = load_settings(DemoSettings, _yaml(tmp_path / "q.yaml", {"demo": {"inner": {"gain": 5}}}), "demo")
    assert part == DemoSettings(inner=Inner(gain=5.0))


def test_yaml_1_1_exponent_without_dot_is_a_number(tmp_path):
    f = tmp_path / "e.yaml"
    f.write_text("demo:\n  rate_hz: 1e-5\n", encoding="utf-8")
    assert yaml.safe_load(f.read_text())["demo"]["rate_hz"] == "1e-5"  # what PyYAML gives
    assert load_settings(DemoSettings, str(f), "demo").rate_hz == pytest.approx(1e-5)


def test_unknown_nested_key_names_file_key_path_suggestion_and_allowed_keys(tmp_path):
    f = _yaml(tmp_path / "drag.yaml", {"fit": {"plateau": {"smoth_s": 0.3}}})
    with pytest.raises(ParamsError) as info:
        load_settings(DragFitSettings, f, "fit")
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f)
    assert "fit.plateau.smoth_s" in msg and "did you mean 'smooth_s'?" in msg
    assert all(name in msg for name in PlateauSettings.__dataclass_fields__)
    assert info.value.key == "fit.plateau.smoth_s" and info.value.path == f
    # a typo far from every key gets the list without a guess
    with pytest.raises(ParamsError, match=r"fit\.zzz: unknown setting 'zzz' \(allowed: plateau,") as info:
        load_settings(DragFitSettings, _yaml(tmp_path / "d2.yaml", {"fit": {"zzz": 1}}), "fit")
    assert "did you mean" not in str(info.value)


@pytest.mark.parametrize("doc, key, fault", [
    ({"count": 2.5}, "demo.count", "must be an integer, got float 2.5"),
    ({"enabled": "yes"}, "demo.enabled", "must be true or false"),
    ({"rate_hz": True}, "demo.rate_hz", "must be a number, got true/false"),
    ({"rate_hz": "fast"}, "demo.rate_hz", "must be a number"),
    ({"cutoff_hz": "high"}, "demo.cutoff_hz", "must be a number"),
    ({"window_s": [1, 2, 3]}, "demo.window_s", "must be a list of 2 values, got 3"),
    ({"window_s": 1.0}, "demo.window_s", "must be a list"),
    ({"inner": {"taps": [1, "x"]}}, "demo.inner.taps[1]", "must be an integer"),
    ({"inner": 7}, "demo.inner", "must be a mapping"),
    ({"extra": [1]}, "demo.extra", "must be a mapping"),
    ({"mode": "exakt"}, "demo.mode", "must be one of 'fast', 'exact', got 'exakt' (did you mean 'exact'?)"),
    ({"count": -1}, "demo", "count must not be negative"),
])
def test_wrong_types_and_failed_checks_name_the_key(tmp_path, doc, key, fault):
    f = _yaml(tmp_path / "p.yaml", {"demo": doc})
    with pytest.raises(ParamsError) as info:
        load_settings(DemoSettings, f, "demo")
    assert str(info.value).startswith(f"{f}, {key}: ") and fault in str(info.value)


def test_which_file_and_which_section(tmp_path, monkeypatch):
    monkeypatch.setenv("WORKBENCH_HOME", str(tmp_path))
    # no --params and no default file: built-in defaults
    assert load_settings(DragFitSettings, None, "fit", default="pipelines/drag.yaml") == DragFitSettings()
    assert load_settings(DragFitSettings, "pipelines/drag.yaml", "fit", default="pipelines/drag.yaml") == DragFitSettings()
    # the default file, found under the project root
    (tmp_path / "pipelines").mkdir()
    _yaml(tmp_path / "pipelines" / "drag.yaml", {"fit": {"min_speeds": 7}})
    assert load_settings(DragFitSettings, None, "fit", default="pipelines/drag.yaml").min_speeds == 7
    # an explicit file that is not there is an error, not the defaults
    with pytest.raises(ParamsError, match="elsewhere.yaml: parameter file not found"):
        load_settings(DragFitSettings, tmp_path / "elsewhere.yaml", "fit", default="pipelines/drag.yaml")
    # a file without the section: an error naming the sections there (or the defaults, when optional)
    other = _yaml(tmp_path / "ingest.yaml", {"ingest": {"lowpass_order": 2}})
    with pytest.raises(ParamsError, match=r"no section 'fit' in parameter file \(sections: ingest\)"):
        load_settings(DragFitSettings, other, "fit")
    assert load_settings(DragFitSettings, other, "fit", required=False) == DragFitSettings()
    with pytest.raises(ParamsError, match="did you mean 'ingest'"):
        read_section(other, "injest")
    # a section written as null is empty; a section that is not a mapping is an error
    assert read_section(_yaml(tmp_path / "n.yaml", {"fit": None}), "fit") == ({}, str(tmp_path / "n.yaml"))
    with pytest.raises(ParamsError, match="fit: must be a mapping of settings, not list"):
        read_section(_yaml(tmp_path / "l.yaml", {"fit": [1, 2]}), "fit")


def test_dotted_section_and_overrides(tmp_path):
    f = _yaml(tmp_path / "g.yaml", {"optimize": {"nsga2": {"pop_size": 12}}, "ingest": {"workers": 1}})
    assert read_section(f, "optimize.nsga2")[0] == {"pop_size": 12}
    with pytest.raises(ParamsError, match="no section 'optimize.nsgaa'"):
        read_section(f, "optimize.nsgaa")
    # CLI flags on top; a flag left at None keeps the file's value
    assert load_settings(IngestSettings, f, "ingest", overrides={"workers": 2}).workers == 2
    assert load_settings(IngestSettings, f, "ingest", overrides={"workers": None}).workers == 1


def test_not_yaml_names_the_line(tmp_path):
    f = tmp_path / "broken.yaml"
    f.write_text("fit:\n  min_r2: 0.9\n  plateau: [1, 2\n", encoding="utf-8")
    with pytest.raises(ParamsError, match=r"broken\.yaml, line \d+: not valid YAML"):
        read_section(str(f), "fit")


def test_build_accepts_a_ready_instance_and_refuses_a_non_mapping():
    s = DragFitSettings(min_speeds=3)
    assert build(DragFitSettings, s, key="fit") is s
    with pytest.raises(ParamsError, match="fit: must be a mapping of settings, not str"):
        build(DragFitSettings, "sem", key="fit")


def _repository_sections():
    from workbench.commands.train_ensemble import EnsembleSettings
    from workbench.gait.config import TrackingSettings as GaitTrackingSettings
    from workbench.gait.problem import SimSettings
    from workbench.gait.run import NSGA2Settings
    from workbench.gait.space import GaitSpace
    from workbench.gait.tabulate import TabulationSettings
    from workbench.hydro.robot import BodyDragSettings, LegsSettings, RobotBodySettings
    from workbench.learn.config import EvaluateSettings, LearnSettings
    from workbench.learn.tune import TuneSettings
    from workbench.signals.interpolation import InterpolationSettings
    from workbench.trials.params import ScoringSettings
    from workbench.virtual_lab.physics import TruthSettings
    from workbench.virtual_lab.pool_settings import PoolSettings

    return [(IngestSettings, "pipelines/ingest.yaml", "ingest"),
            (InterpolationSettings, "pipelines/ingest.yaml", "interpolate"),
            (DragFitSettings, "pipelines/drag.yaml", "fit"),
            (ScoringSettings, "pipelines/trials.yaml", "scoring"),
            (NSGA2Settings, "pipelines/gait.yaml", "optimize.nsga2"),
            (LearnSettings, "pipelines/learn.yaml", "train"),
            (TuneSettings, "pipelines/learn.yaml", "tune"),
            (EvaluateSettings, "pipelines/learn.yaml", "evaluate"),
            (PoolSettings, "pipelines/trials.yaml", "pool"),
            (TruthSettings, "pipelines/virtual_lab.yaml", "tunnel.physics"),
            (RobotBodySettings, "pipelines/robot.yaml", "robot"),
            (EnsembleSettings, "pipelines/plan.yaml", "ensemble"),
            (GaitSpace, "pipelines/gait.yaml", "optimize.space"),
            (SimSettings, "pipelines/gait.yaml", "optimize.simulation"),
            (TabulationSettings, "pipelines/gait.yaml", "optimize.tabulation"),
            (GaitTrackingSettings, "pipelines/gait.yaml", "optimize.tracking"),
            (LegsSettings, "pipelines/robot.yaml", "legs"),
            (BodyDragSettings, "pipelines/robot.yaml", "body_drag")]


def _same(value, raw) -> bool:
    if hasattr(value, "__dataclass_fields__"):
        return _same_settings(value, raw)
    if isinstance(raw, dict):
        return isinstance(value, dict) and set(value) == set(raw) and all(_same(value[k], v) for k, v in raw.items())
    if isinstance(value, (tuple, list)):
        return isinstance(raw, list) and len(value) == len(raw) and all(_same(a, b) for a, b in zip(value, raw, strict=True))
    return value == raw and isinstance(value, bool) == isinstance(raw, bool)


def _same_settings(value, raw) -> bool:
    """Every value the file gives arrives unchanged; every key it leaves out keeps the class's default."""
    import dataclasses

    for f in dataclasses.fields(value):
        if f.name in raw:
            ok = _same(getattr(value, f.name), raw[f.name])
        else:
            default = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
            ok = getattr(value, f.name) == default
        if not ok:
            return False
    return set(raw) <= {f.name for f in dataclasses.fields(value)}


@pytest.mark.parametrize("cls, file, section", _repository_sections(), ids=lambda x: getattr(x, "__name__", x))
def test_the_repository_parameter_files_load_and_every_value_arrives(cls, file, section):
    path = REPO / file
    raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    for part in section.split("."):
        raw = raw[part]
    s = load_settings(cls, path, section)
    assert raw and _same_settings(s, raw)
    assert not _same_settings(s, {**raw, next(iter(raw)): "changed"})  # the check itself can fail


def test_the_migrated_loaders_read_the_repository_files_like_load_settings():
    from workbench.hydro.robot import RobotSettings, load_robot
    from workbench.learn.config import LearnSettings, load_config

    assert load_config(REPO / "pipelines/learn.yaml") == load_settings(LearnSettings, REPO / "pipelines/learn.yaml",
                                                                       "train")
    assert load_robot(REPO / "pipelines/robot.yaml") == RobotSettings()  # the documented defaults are the file's


def test_the_gait_file_loads_every_top_level_value_and_task_unchanged():
    from workbench.gait.config import load_config

    raw = yaml.safe_load((REPO / "pipelines/gait.yaml").read_text(encoding="utf-8"))["optimize"]
    cfg = load_config(REPO / "pipelines/gait.yaml")
    for key, value in raw.items():
        if key != "tasks":
            assert _same(getattr(cfg, key), value), key
    assert set(cfg.tasks) == set(raw["tasks"]) == {"straight", "turn"}
    for name, task in raw["tasks"].items():
        got = cfg.task(name)
        assert list(got.hv_reference) == task["hv_reference"]
        assert _same_settings(got.spec, {**{k: v for k, v in task.items() if k != "hv_reference"}, "task": name,
                                         "weights": raw["weights"]})


@pytest.mark.parametrize("argv", [
    ["fit-drag", "{tmp}/no-campaign", "--out", "{tmp}/out", "--params", "{bad}"],
    ["interpolate", "{tmp}/none.parquet", "--out", "{tmp}/out.parquet", "--params", "{bad}"],
    ["ingest", "{tmp}/no-campaign", "--out", "{tmp}/out.parquet", "--params", "{bad}"],
    ["score-trials", "{tmp}/no-trials", "--out", "{tmp}/out", "--params", "{bad}"],
    ["train", "--config", "{bad}", "--data", "{tmp}/none.parquet", "--no-mlflow"],
    ["train-ensemble", "--data", "{tmp}/none.parquet", "--out", "{tmp}/out", "--params", "{bad}", "--no-mlflow"],
    ["virtual-lab", "pool", "{tmp}/out", "--synthetic", "--params", "{bad}"],
    ["simulate", "--gait", "theta_h_min_deg=-30", "theta_k_max_deg=-60", "frequency_hz=0.4", "alpha_rad=0,1,2,3",
     "--robot", "{bad}", "--duration", "1", "--out", "{tmp}/out"],
])
def test_a_typo_in_a_params_file_is_one_line_and_status_2(tmp_path, capsys, argv):
    bad = _yaml(tmp_path / "bad.yaml", {
        "fit": {"plateau": {"setle_s": 0.5}}, "interpolate": {"speed_mps": [0.1]},
        "ingest": {"lowpass_cutof_hz": 5.0}, "scoring": {"sat_minn": 3}, "train": {"model": {"hiden_size": 3}},
        "ensemble": {"member": 3}, "pool": {"fsp": 3}, "legs": {"haa_angel_deg": [0, 0, 0, 0]}})
    argv = [a.format(tmp=tmp_path, bad=bad) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {bad}, ") and "\n" not in err and "unknown setting" in err
    assert "did you mean" in err
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.parquet").exists()


def test_the_real_command_prints_one_line_and_exits_2(tmp_path):
    bad = _yaml(tmp_path / "bad.yaml", {"fit": {"weighting": "semm"}})
    proc = subprocess.run([sys.executable, "-m", "workbench", "fit-drag", str(tmp_path / "c"), "--out",
                           str(tmp_path / "o"), "--params", bad], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.strip() == (f"error: {bad}, fit.weighting: must be one of 'sem', 'none', got 'semm' "
                                   "(did you mean 'sem'?)")


def test_params_error_is_a_workbench_error_but_not_a_contract_error():
    from workbench.errors import ContractError

    assert issubclass(ParamsError, WorkbenchError) and not issubclass(ParamsError, ContractError)


def test_virtual_lab_sections_split_into_campaign_and_rig_settings(tmp_path, capsys):
    from workbench.virtual_lab.settings import TowingSettings, TunnelSettings, campaign_and_rig

    doc = yaml.safe_load((REPO / "pipelines" / "virtual_lab.yaml").read_text(encoding="utf-8"))
    for key, rig_cls in (("tunnel", TunnelSettings), ("towing", TowingSettings)):
        campaign, rig = campaign_and_rig(doc[key], key, "virtual_lab.yaml")
        assert isinstance(rig, rig_cls) and campaign.seed == doc[key]["seed"] and rig.date == str(doc[key]["date"])
    camp, rig = campaign_and_rig(doc["tunnel"], "tunnel")
    assert camp.flow_speeds_mps == tuple(doc["tunnel"]["flow_speeds_mps"])
    assert rig.loadcell.full_scale == tuple(doc["tunnel"]["loadcell"]["full_scale"])
    with pytest.raises(ParamsError, match=r"tunnel\.sed: unknown setting 'sed' \(did you mean 'seed'\? allowed: "
                                          r"scale, seed, .*loadcell, motion"):
        campaign_and_rig({"sed": 3}, "tunnel")
    with pytest.raises(ParamsError, match=r"towing\.seed: must be an integer, got str 'zero'"):
        campaign_and_rig({"seed": "zero"}, "towing")
    bad = _yaml(tmp_path / "vl.yaml", {"tunnel": {"motion": {"rest_befor_s": 1.0}}})
    assert main(["virtual-lab", "tunnel", str(tmp_path / "t"), "--params", bad]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"error: {bad}, tunnel.motion.rest_befor_s: unknown setting 'rest_befor_s' (did you mean "
                   "'rest_before_s'? allowed: rate_hz, feedback, rest_before_s, rest_after_s, ease_s, "
                   "feedback_noise_deg, feedback_resolution_deg)")
    assert not (tmp_path / "t").exists()


def test_a_list_left_empty_is_empty_and_diagnose_names_the_key_path(tmp_path, capsys):
    f = tmp_path / "d.yaml"
    f.write_text("diagnose:\n  library:\n    effects:\n  fit:\n    surrogate_serch: auto\n", encoding="utf-8")
    from workbench.diagnose.loop import DiagnoseSettings

    raw, source = read_section(str(f), "diagnose")
    assert raw["library"]["effects"] is None  # what YAML gives for an empty key
    with pytest.raises(ParamsError) as info:
        DiagnoseSettings.from_mapping(raw, source)
    assert str(info.value).startswith(f"{f}, diagnose.fit.surrogate_serch: unknown setting 'surrogate_serch' "
                                      "(did you mean 'surrogate_search'?")
    del raw["fit"]
    assert DiagnoseSettings.from_mapping(raw, source).library.effects == ()
    assert main(["diagnose", "--processed", str(tmp_path / "none.parquet"), "--out", str(tmp_path / "o"),
                 "--params", str(f), "--no-mlflow"]) == 2
    assert "diagnose.fit.surrogate_serch" in capsys.readouterr().err


def test_callers_get_their_own_copy_of_a_cached_file(tmp_path):
    from workbench.project import load_params

    f = _yaml(tmp_path / "p.yaml", {"demo": {"inner": {"taps": [1, 2]}}})
    raw, _ = read_section(f, "demo")
    raw["inner"]["taps"].append(99)  # e.g. a --set override applied in place
    load_params(f)["demo"]["inner"]["gain"] = 7.0
    assert read_section(f, "demo")[0] == {"inner": {"taps": [1, 2]}}


def test_set_dotted_makes_sections_and_build_names_a_misspelt_key():
    from workbench.params import set_dotted

    doc = {"inner": {"gain": 2.0}, "label": None}
    set_dotted(doc, "inner.taps", [4, 5], section="demo")
    set_dotted(doc, "rate_hz", 20, section="demo")
    s = build(DemoSettings, doc, key="demo", path="d.yaml")
    assert s.inner == Inner(gain=2.0, taps=(4, 5)) and s.rate_hz == 20.0
    set_dotted(doc, "inner.gian", 1.0, section="demo")
    with pytest.raises(ParamsError, match=r"^d\.yaml, demo\.inner\.gian: unknown setting 'gian' \(did you mean 'gain'"):
        build(DemoSettings, doc, key="demo", path="d.yaml")
    with pytest.raises(ParamsError, match=r"^d\.yaml, demo\.label\.x: 'label' is not a section"):
        set_dotted(doc, "label.x", 1, section="demo", path="d.yaml")


ALIASES = {  # the names before issue 17 -> the settings class they stand for (kept for outside imports)
    "workbench.hydro.drag": {"DragFitParams": "DragFitSettings", "PlateauParams": "PlateauSettings"},
    "workbench.hydro.robot": {"RobotParams": "RobotSettings"},
    "workbench.signals.interpolation": {"InterpolationParams": "InterpolationSettings"},
    "workbench.ingest.params": {"IngestParams": "IngestSettings"},
    "workbench.trials.params": {"ScoringParams": "ScoringSettings"},
    "workbench.virtual_lab.physics": {"TruthParams": "TruthSettings"},
    "workbench.gait.config": {"OptimizeConfig": "OptimizeSettings"},
    "workbench.learn.tune": {"TuneCfg": "TuneSettings"},
    "workbench.learn.config": {"LearnConfig": "LearnSettings", "SplitCfg": "SplitSettings", "DataCfg": "DataSettings",
                               "ModelCfg": "ModelSettings", "OptimCfg": "OptimSettings",
                               "TrainerCfg": "TrainerSettings", "TrackingCfg": "TrackingSettings"},
}


def test_old_settings_names_are_the_same_classes():
    import importlib

    for module, names in ALIASES.items():
        mod = importlib.import_module(module)
        for old, new in names.items():
            assert getattr(mod, old) is getattr(mod, new), f"{module}.{old}"


def test_the_package_uses_one_name_per_settings_class():
    """The old names are defined once, as aliases, and used nowhere else in the package (one naming)."""
    import re

    old = sorted(n for names in ALIASES.values() for n in names)
    word = re.compile(r"\b(%s)\b" % "|".join(old))
    uses = []
    for path in sorted((REPO / "workbench").rglob("*.py")):
        for i, line in enumerate(path.read_text().splitlines(), 1):
            m = word.search(line)
            if not m or re.match(r"^(%s) = \w+Settings$" % "|".join(old), line):
                continue
            if path.name == "__init__.py" or "name before issue 17" in line or "earlier names" in line \
                    or line.lstrip().startswith(("``", "...")):
                continue  # re-exports for outside imports, and the docstrings that name the aliases
            uses.append(f"{path.relative_to(REPO)}:{i}: {line.strip()}")
    assert not uses, "\n".join(uses)
