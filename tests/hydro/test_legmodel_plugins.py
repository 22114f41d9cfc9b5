"""Leg force models come from the ``workbench.leg_models`` entry-point group (one table, pyproject.toml).

A test-local distribution (a ``*.dist-info`` folder with ``entry_points.txt`` on ``sys.path``, what pip
writes) declares a leg model; ``workbench simulate --model NAME`` finds it through the real
``importlib.metadata``; a broken entry is a one-line error naming it.
"""

from __future__ import annotations

import json
import sys
import textwrap
import tomllib
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from workbench.cli import main
from workbench.errors import ModelError, ModelLoadError
from workbench.hydro import legmodel

ROOT = Path(__file__).resolve().parents[2]
GAIT = ["--gait", "theta_h_min_deg=-30", "theta_k_max_deg=-60", "frequency_hz=0.4", "alpha_rad=0,1,2,3"]

# a plug-in package: a leg that is the EF scaled by a factor (by name: 0, i.e. a leg with no force)
PLUGIN = textwrap.dedent('''
    from workbench.hydro.ef import EmpiricalFormula
    from workbench.hydro.legmodel import LegForceModel

    CALLS = []

    class ScaledEF(LegForceModel):
        def __init__(self, factor=0.0):
            self.factor, self.ef, self.name = factor, EmpiricalFormula(), f"scaled-ef-{factor:g}"

        def wrench(self, motion):
            CALLS.append(self.factor)
            return self.factor * self.ef.wrench(motion)

    def scaled(spec):                    # "scaled:<factor>"
        return ScaledEF(float(spec.split(":", 1)[1]))
''')


def _install(root: Path, dist: str, entries: dict[str, str], module: str | None = None) -> None:
    """Write what pip writes for a distribution declaring ``workbench.leg_models`` entry points."""
    if module:
        (root / "lab_legs_plugin.py").write_text(module)
    info = root / f"{dist}-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 0.1\n")
    body = "".join(f"{k} = {v}\n" for k, v in entries.items())
    (info / "entry_points.txt").write_text(f"[{legmodel.ENTRY_POINT_GROUP}]\n{body}")


@pytest.fixture
def plugin_path(tmp_path, monkeypatch):
    """A folder on sys.path for test-local distributions; the table is re-read before and after."""
    monkeypatch.syspath_prepend(str(tmp_path))
    legmodel.refresh()
    yield tmp_path
    monkeypatch.undo()
    sys.modules.pop("lab_legs_plugin", None)
    legmodel.refresh()


def _final_x(out: Path) -> float:
    return json.loads((out / "summary.json").read_text())["gaits"][0]["final_x_m"]


def test_simulate_finds_a_leg_model_declared_by_an_installed_package(plugin_path, tmp_path, capsys):
    _install(plugin_path, "lab_legs", {"no-force-leg": "lab_legs_plugin:ScaledEF", "scaled:": "lab_legs_plugin:scaled"},
             module=PLUGIN)
    assert main(["simulate", *GAIT, "--model", "no-force-leg", "--duration", "1", "--out", str(tmp_path / "zero")]) == 0
    assert main(["simulate", *GAIT, "--model", "scaled:1", "--duration", "1", "--out", str(tmp_path / "one")]) == 0
    calls = sys.modules["lab_legs_plugin"].CALLS
    assert set(calls) == {0.0, 1.0}                    # both entries built the plug-in's model and the simulator used it
    summary = json.loads((tmp_path / "zero" / "summary.json").read_text())
    assert summary["model"] == "no-force-leg"
    # physics, not bookkeeping: a leg with no force leaves the robot where it started; the EF times 1 swims
    assert abs(_final_x(tmp_path / "zero")) < 1e-9
    assert abs(_final_x(tmp_path / "one")) > 1e-3


@pytest.mark.parametrize("target, message", [
    ("no_such_module_xyz:Leg", r"entry point broken-leg = no_such_module_xyz:Leg \(workbench.leg_models\) does not "
                               r"load: ModuleNotFoundError"),
    ("workbench.hydro.ef:NoSuchClass", r"broken-leg = workbench.hydro.ef:NoSuchClass .* has no 'NoSuchClass'"),
    ("not a target", r"broken-leg = not a target .* is not a 'module:callable' path"),
])
def test_a_broken_entry_is_a_one_line_error_naming_it(plugin_path, tmp_path, capsys, target, message):
    _install(plugin_path, "broken_legs", {"broken-leg": target})
    with pytest.raises(ModelLoadError, match=message):
        legmodel.load_leg_model("broken-leg")
    assert legmodel.load_leg_model("ef").name == "ef"  # a broken entry breaks only itself
    assert main(["simulate", *GAIT, "--model", "broken-leg", "--duration", "1", "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and "broken-leg" in err
    assert not (tmp_path / "s").exists()


def test_register_loader_still_adds_models_at_run_time(plugin_path, monkeypatch):
    from workbench.hydro.ef import EmpiricalFormula

    monkeypatch.setattr(legmodel, "_LOADERS", {"ef-again": "workbench.hydro.ef:EmpiricalFormula"})
    monkeypatch.setattr(legmodel, "_PREFIX_LOADERS", {"twice:": lambda spec: EmpiricalFormula()})
    assert isinstance(legmodel.load_leg_model("ef-again"), EmpiricalFormula)
    assert isinstance(legmodel.load_leg_model("twice:whatever"), EmpiricalFormula)
    with pytest.raises(ModelError, match=r"unknown leg force model 'nope' \(known: .*ef-again.*twice:"):
        legmodel.load_leg_model("nope")


def test_the_installed_table_is_pyprojects():
    """A stale editable install (pyproject edited, not reinstalled) fails here, saying what to run."""
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]
    declared = declared[legmodel.ENTRY_POINT_GROUP]
    installed = {ep.name: ep.value for ep in entry_points(group=legmodel.ENTRY_POINT_GROUP)
                 if ep.dist is not None and ep.dist.name == "workbench"}
    assert installed == declared, "run `pip install -e . --no-deps` (make setup does it)"
    for name, target in declared.items():  # every in-tree entry resolves
        assert callable(legmodel._resolve(name, target)), name
