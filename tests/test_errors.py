"""Typed errors at the source (issue 17.4).

Every module of ``workbench/`` raises the typed subclasses of ``workbench/errors.py`` where a fault
is found, never a bare ``ValueError``/``RuntimeError``/``Exception`` or the bare root ``WorkbenchError``;
a caller that catches a parameter fault (``ValueError``, ``SettingError``, ``ParamsError``) adds the
file (``exc.located(path=...)``) instead of re-labelling it a ``ContractError``; a raise saying a
solver did not converge is a ``ConvergenceError`` (AST walks, below, with their allow-lists). A
setting's bad value is a :class:`SettingError`, which the loader that read the file turns into a
one-line message naming file and key, and which old ``except ValueError`` callers still catch.
"""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

import pytest
import yaml

from workbench.errors import ContractError, ParamsError, SettingError, WorkbenchError

ROOT = Path(__file__).resolve().parents[1]
MODULES = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "workbench").rglob("*.py"))

#: classes a fault must not be raised as: Python's generic errors and the bare root (raise a subclass
#: from workbench/errors.py). TypeError, KeyError, AttributeError, NotImplementedError, OSError stay
#: allowed: the protocols that call our code expect them (a JSON ``default`` hook raises TypeError,
#: ``__getattr__`` AttributeError, an abstract method NotImplementedError).
UNTYPED = {"ValueError", "RuntimeError", "Exception", "WorkbenchError"}
#: a dunder protocol method (``__eq__``, ``__getitem__``, ``__iter__``, ...) may raise what its protocol
#: names (``__init__`` and ``__post_init__`` check settings: they raise SettingError like the rest)
NOT_PROTOCOL = {"__init__", "__post_init__", "__new__", "__call__"}
#: untyped raises kept on purpose: (module, function, raised class, why). Empty today: the last one
#: (a decision vector of the wrong width in gait/space.py) is a SettingError naming space.extension.
ALLOWED: tuple[tuple[str, str, str, str], ...] = ()

#: a parameter fault caught here must not be re-labelled as a contract fault: re-raise it with the
#: file added (``raise exc.located(path=...)``) or as a SettingError/ParamsError naming the option
CAUGHT = {"ValueError", "SettingError", "ParamsError"}
RELABELLED = {"ContractError", "OutputError"}
#: except-ValueError-raise-ContractError kept on purpose: (module, function, why)
RELABEL_ALLOWED: tuple[tuple[str, str, str], ...] = (
    ("workbench/virtual_lab/tunnel.py", "read_plan",
     "float() of a field of a tunnel plan (plan.toml, a data file the contract describes), not a setting"),
)

#: what a raise about a solver that did not converge must be
CONVERGENCE = re.compile(r"(did|does|could) not converge|failed to converge|no convergence", re.IGNORECASE)


def _name(node: ast.expr | None) -> str | None:
    """The class name a ``raise`` or ``except`` refers to (``X``, ``X(...)``, ``errors.X``)."""
    node = node.func if isinstance(node, ast.Call) else node
    return node.id if isinstance(node, ast.Name) else node.attr if isinstance(node, ast.Attribute) else None


def _functions(tree: ast.AST):
    """(enclosing function name or "", node) for every node of ``tree``."""
    stack = [(tree, "")]
    while stack:
        node, fn = stack.pop()
        for child in ast.iter_child_nodes(node):
            name = child.name if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)) else fn
            yield name, child
            stack.append((child, name))


@functools.lru_cache(maxsize=None)
def _parsed_text(src: str, filename: str) -> tuple[tuple[str, ast.AST], ...]:
    """Every node of a module with its enclosing function (parsed and walked once per source text)."""
    return tuple(_functions(ast.parse(src, filename=filename)))


def _nodes(path: Path) -> tuple[tuple[str, ast.AST], ...]:
    return _parsed_text(path.read_text(encoding="utf-8"), str(path))


def _untyped_raises(path: Path, allowed: tuple[tuple[str, str], ...] = ()) -> list[tuple[int, str]]:
    """(line, class) of each raise of an untyped class, but in protocol methods and ``allowed`` (function, class)."""
    out = []
    for fn, node in _nodes(path):
        if isinstance(node, ast.Raise) and node.exc is not None and _name(node.exc) in UNTYPED:
            protocol = fn.startswith("__") and fn.endswith("__") and fn not in NOT_PROTOCOL
            if not protocol and (fn, _name(node.exc)) not in allowed:
                out.append((node.lineno, _name(node.exc)))
    return sorted(out)


def _relabelled(path: Path, allowed: tuple[str, ...] = ()) -> list[tuple[int, str]]:
    """(line, caught classes) of each ``except <parameter fault>: raise ContractError`` but in ``allowed`` functions."""
    out = []
    for fn, node in _nodes(path):
        if isinstance(node, ast.ExceptHandler) and node.type is not None and fn not in allowed:
            caught = {_name(t) for t in (node.type.elts if isinstance(node.type, ast.Tuple) else [node.type])}
            raised = {_name(r.exc) for stmt in node.body for r in ast.walk(stmt) if isinstance(r, ast.Raise)}
            if caught & CAUGHT and raised & RELABELLED:
                out.append((node.lineno, ",".join(sorted(caught & CAUGHT))))
    return sorted(out)


def _convergence_raises(path: Path) -> list[tuple[int, str]]:
    """(line, class) of each raise whose message says a solver did not converge but is no ConvergenceError."""
    src = path.read_text(encoding="utf-8")
    out = []
    for _fn, node in _parsed_text(src, str(path)):
        if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call) and _name(node.exc) != "ConvergenceError":
            if CONVERGENCE.search(ast.get_source_segment(src, node.exc) or ""):
                out.append((node.lineno, _name(node.exc)))
    return out


def test_the_walks_find_what_they_look_for(tmp_path):
    src = tmp_path / "m.py"
    src.write_text("def f(x):\n    if x:\n        raise ValueError('bad')\n    raise errors.WorkbenchError\n"
                   "class A:\n    def __eq__(self, o):\n        raise RuntimeError('protocol')\n"
                   "    def __post_init__(self):\n        raise ValueError('a setting')\n"
                   "def g(v):\n    try:\n        float(v)\n    except (TypeError, SettingError) as exc:\n"
                   "        raise errors.ContractError(str(exc)) from None\n"
                   "    raise DataError(f'the fit did not converge in {v} steps')\n")
    assert _untyped_raises(src) == [(3, "ValueError"), (4, "WorkbenchError"), (9, "ValueError")]
    assert _untyped_raises(src, (("f", "ValueError"),)) == [(4, "WorkbenchError"), (9, "ValueError")]
    assert _relabelled(src) == [(13, "SettingError")] and _relabelled(src, ("g",)) == []
    assert _convergence_raises(src) == [(15, "DataError")]


@pytest.mark.slow  # 4.7 s of CPU idle: an AST walk of every module (29 Nov 2026)
def test_every_module_raises_typed_errors():
    """One walk over all modules (one test, not one per module: ~170 tests cost 3 s of fixture set-up)."""
    faults = []
    for module in MODULES:
        allowed = tuple((fn, name) for mod, fn, name, _ in ALLOWED if mod == module)
        for line, name in _untyped_raises(ROOT / module, allowed):
            faults.append(f"{module}:{line}: raise {name}: raise a subclass from workbench/errors.py")
        for line, caught in _relabelled(ROOT / module, tuple(fn for mod, fn, _ in RELABEL_ALLOWED if mod == module)):
            faults.append(f"{module}:{line}: except {caught} re-raised as a ContractError: raise "
                          "exc.located(path=...) (the same class, with the file) or a SettingError")
        for line, name in _convergence_raises(ROOT / module):
            faults.append(f"{module}:{line}: 'did not converge' raised as {name}: raise ConvergenceError")
    assert len(MODULES) > 100 and not faults, "\n".join(faults)


def test_every_allowed_exception_is_still_there():
    for module, fn, name, _ in ALLOWED:  # an entry the code no longer needs is removed from the list
        assert _untyped_raises(ROOT / module) != _untyped_raises(ROOT / module, ((fn, name),)), (module, fn)
    for module, fn, _ in RELABEL_ALLOWED:
        assert _relabelled(ROOT / module) != _relabelled(ROOT / module, (fn,)), (module, fn)


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
    with pytest.raises(SettingError) as info:  # the class RobotSettings raised, with the file added
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


def test_located_fills_only_what_the_error_lacks_and_keeps_its_class():
    from workbench.errors import CampaignRefused, ConvergenceError

    e = SettingError("must be positive", where="robot.mass_kg", hint="e.g. 2.0")
    got = e.located(path="r.yaml", where="robot")
    assert type(got) is SettingError and got.where == "robot.mass_kg" and got.path == "r.yaml"
    assert str(got) == "r.yaml, robot.mass_kg: must be positive (e.g. 2.0)" and e.path is None
    assert str(ConvergenceError("did not converge", path="a.json").located(path="b.json", run="T1")) == \
        "a.json, run T1: did not converge"
    refused = CampaignRefused("camp", [ContractError("bad", run="T2")]).located(path="other")
    assert isinstance(refused, CampaignRefused) and refused.path == "camp" and refused.errors[0].run == "T2"


def test_a_bad_thread_setting_in_a_train_section_names_file_and_key(tmp_path):
    from workbench.learn.config import config_from_dict

    with pytest.raises(SettingError) as info:
        config_from_dict({"trainer": {"torch_threads": 0}}, path=tmp_path / "learn.yaml")
    e = info.value
    assert e.path == str(tmp_path / "learn.yaml") and e.where == "train.trainer.torch_threads"
    assert "torch_threads must be a positive integer" in str(e) and "\n" not in str(e)


def test_bad_rig_ranges_of_a_plan_name_file_and_section(tmp_path):
    from workbench.plan.acquisition import RigRanges

    with pytest.raises(SettingError, match="frequency_hz: lower bound 0.6 above upper bound 0.2"):
        RigRanges(frequency_hz=(0.6, 0.2))
    with pytest.raises(ParamsError) as info:
        RigRanges.from_dict({"cycles": 0}, path=tmp_path / "plan.yaml")
    assert info.value.path == str(tmp_path / "plan.yaml") and info.value.key == "plan.ranges"
    assert "cycles >= 1" in str(info.value)


def test_decision_vectors_of_another_space_name_the_extension():
    import numpy as np

    from workbench.gait.space import GaitSpace

    with pytest.raises(SettingError, match=r"decision vectors of space.extension 'per_side_range' need 9 entries"):
        GaitSpace(extension="per_side_range").gaits(np.zeros((2, 7)))


def test_gait_values_that_are_not_numbers_name_the_gait():
    from workbench.hydro.simulator import GaitBatch

    good = {"theta_h_min_deg": -30, "theta_k_max_deg": -60, "frequency_hz": 0.4, "alpha_rad": 0}
    with pytest.raises(SettingError) as info:
        GaitBatch.from_params([good, {**good, "alpha_rad": "zero"}], labels=["a #1", "a #2"])
    assert info.value.where == "a #2" and "gait parameters must be numbers" in str(info.value)
    with pytest.raises(SettingError, match="must be a table"):
        GaitBatch.from_params([good, [1, 2, 3]])
