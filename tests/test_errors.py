"""Typed errors at the source (issue 17.4).

The modules converted so far raise the typed subclasses of ``workbench/errors.py`` where a fault is
found, never a bare ``ValueError``/``RuntimeError``/``Exception`` or the bare root ``WorkbenchError``
(an AST walk, below); a setting's bad value is a :class:`SettingError`, which the loader that read
the file turns into a one-line message naming file and key, and which old ``except ValueError``
callers still catch.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import yaml

from workbench.errors import ContractError, ParamsError, SettingError, WorkbenchError

ROOT = Path(__file__).resolve().parents[1]

#: modules whose raises were converted; each must stay free of untyped raises
CONVERTED = (
    "workbench/hydro/robot.py",
    "workbench/hydro/legmodel.py",
    "workbench/threads.py",
    "workbench/procs.py",
    "workbench/ingest/readers/base.py",
    "workbench/hydro/simulator.py",
    "workbench/gait/space.py",
    "workbench/gait/objectives.py",
    "workbench/gait/tabulate.py",
    "workbench/gait/config.py",
    "workbench/gait/cycles.py",
    "workbench/gait/problem.py",
)
CONVERTED += tuple(sorted(str(p.relative_to(ROOT)) for p in (ROOT / "workbench/virtual_lab").glob("*.py")))
#: untyped raises kept on purpose: (module, raised name, text of the raise, why)
DELIBERATE: tuple[tuple[str, str, str, str], ...] = (
    ("workbench/gait/space.py", "ValueError", "decision vectors need",
     "a caller's programming error (pymoo hands over arrays of the space's own width), not user input"),
)
UNTYPED = {"ValueError", "RuntimeError", "Exception", "WorkbenchError"}


def _untyped_raises(path: Path, allowed: tuple[tuple[str, str], ...] = ()) -> list[tuple[int, str]]:
    """(line, class) of each raise of an untyped class, but those whose source holds an allowed text."""
    src = path.read_text(encoding="utf-8")
    out = []
    for node in ast.walk(ast.parse(src, filename=str(path))):
        if isinstance(node, ast.Raise) and node.exc is not None:
            exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
            name = exc.id if isinstance(exc, ast.Name) else exc.attr if isinstance(exc, ast.Attribute) else None
            text = ast.get_source_segment(src, node) or ""
            if name in UNTYPED and not any(name == n and t in text for n, t in allowed):
                out.append((node.lineno, name))
    return sorted(out)


def test_the_walk_finds_what_it_looks_for(tmp_path):
    src = tmp_path / "m.py"
    src.write_text("def f(x):\n    if x:\n        raise ValueError('bad')\n    raise errors.WorkbenchError\n")
    assert _untyped_raises(src) == [(3, "ValueError"), (4, "WorkbenchError")]


@pytest.mark.parametrize("module", CONVERTED)
def test_converted_modules_raise_typed_errors_only(module):
    allowed = tuple((name, text) for mod, name, text, _ in DELIBERATE if mod == module)
    found = _untyped_raises(ROOT / module, allowed)
    assert not found, f"{module}: untyped raise(s) at {found}: raise a subclass from workbench/errors.py"


def test_every_deliberate_exception_is_still_there():
    for module, name, text, _ in DELIBERATE:  # an entry the code no longer needs is removed from the list
        assert _untyped_raises(ROOT / module) != _untyped_raises(ROOT / module, ((name, text),)), (module, text)


def test_a_gait_setting_in_a_parameter_file_names_file_and_key(tmp_path):
    from workbench.gait.config import load_config
    from workbench.gait.space import GaitSpace

    with pytest.raises(SettingError, match="space.extension must be one of"):
        GaitSpace(extension="sideways")
    doc = yaml.safe_load((ROOT / "pipelines/gait.yaml").read_text())
    doc["optimize"]["space"]["extension"] = "sideways"
    p = tmp_path / "gait.yaml"
    p.write_text(yaml.safe_dump(doc))
    with pytest.raises(ParamsError) as info:
        load_config(p)
    assert info.value.path == str(p) and "space.extension must be one of" in str(info.value)


def test_a_simulator_setting_is_a_setting_error():
    from workbench.hydro.simulator import GaitBatch, simulation_settings

    with pytest.raises(SettingError, match="gait parameters must be finite with positive frequency"):
        GaitBatch.from_params([{"theta_h_min_deg": -30, "theta_k_max_deg": -60, "frequency_hz": 0.0, "alpha_rad": 0}])
    with pytest.raises(ParamsError):
        simulation_settings({"method": "leapfrog"})


def test_a_setting_error_is_a_params_error_and_still_a_value_error():
    from workbench.threads import check_setting

    with pytest.raises(SettingError, match=r"torch_threads must be a positive integer.*not 0") as info:
        check_setting(0)
    assert isinstance(info.value, ParamsError) and isinstance(info.value, ValueError)
    assert "\n" not in str(info.value)


def _robot_file(tmp_path, **robot):
    doc = yaml.safe_load((ROOT / "pipelines/robot.yaml").read_text())
    doc["robot"].update(robot)
    p = tmp_path / "robot.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


def test_a_bad_robot_value_names_the_file_and_the_fault(tmp_path):
    from workbench.hydro.robot import load_robot

    assert load_robot(_robot_file(tmp_path)).mass_kg == 2.0  # the repository's file, copied: loads
    bad = _robot_file(tmp_path, mass_kg=-2.0)
    with pytest.raises(ParamsError) as info:
        load_robot(bad)
    assert info.value.path == str(bad) and "mass_kg and yaw_inertia_kgm2 must be positive" in str(info.value)


def test_the_cli_prints_it_on_one_line(tmp_path, capsys):
    from workbench.cli import main

    bad = _robot_file(tmp_path, yaw_inertia_kgm2=0.0)
    assert main(["simulate", "--gait", "theta_h_min_deg=-30", "theta_k_max_deg=-60", "frequency_hz=0.4",
                 "alpha_rad=0,1,2,3", "--robot", str(bad), "--duration", "1", "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {bad}") and "must be positive" in err and "\n" not in err
    assert not (tmp_path / "s").exists()


def test_a_bad_date_in_a_virtual_lab_section_names_file_and_key(tmp_path):
    from workbench.params import build
    from workbench.virtual_lab.settings import TowingSettings

    with pytest.raises(ParamsError) as info:
        build(TowingSettings, {"date": "2025-13-40"}, key="towing", path=tmp_path / "lab.yaml")
    e = info.value
    assert e.path == str(tmp_path / "lab.yaml") and e.key == "towing" and "'2025-13-40' is not YYYY-MM-DD" in str(e)


def test_an_unknown_stream_role_is_a_contract_error_naming_the_run():
    from workbench.ingest.readers.base import ReadSpec

    with pytest.raises(ContractError, match=r"run T03: unknown stream role 'sonar'"):
        ReadSpec(run="T03", facility="water_tunnel").columns("sonar")


def test_every_error_class_is_one_workbench_error():
    import workbench.errors as errors

    classes = [c for c in vars(errors).values() if isinstance(c, type) and issubclass(c, Exception)]
    assert all(issubclass(c, WorkbenchError) for c in classes), classes
