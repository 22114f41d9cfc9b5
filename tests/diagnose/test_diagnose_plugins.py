"""Effects are plug-ins: one table (entry points + in-tree modules), no names in the loop, no import cycle.

A new effect defined here, in the test module, and registered through the same table as the
library's effects, is fitted and named by the loop on a campaign whose raw load-cell files were
edited with this test's own formula (not the effect's code).
"""

from __future__ import annotations

import ast
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import numpy as np
import pytest

from workbench.diagnose import library
from workbench.diagnose.effects.base import ALL_CHANNELS, Effect, Terms
from workbench.errors import ModelError

ROOT = Path(__file__).resolve().parents[2]
PKG = ROOT / "workbench" / "diagnose"
#: the code that runs the diagnosis: it asks effects through their hooks and never names one
GENERIC = ["loop.py", "loop_claims.py", "loop_results.py", "loop_settings.py", "loop_threads.py", "selection.py",
           "selection_candidates.py", "selection_claims.py", "selection_finish.py", "selection_judge.py",
           "selection_records.py", "selection_search.py",
           "problem.py", "chain.py", "lsq.py", "data.py", "evidence.py", "evidence_base.py", "evidence_locked.py",
           "evidence_lines.py", "evidence_tones.py", "evidence_dependence.py"]


class HipSpring(Effect):
    """A cable spring on the hip shaft: tx += k_nm sin(theta_h) (not in the library)."""

    name = "hip_spring"
    formula = "tx += k_nm sin(theta_h)"
    ranges = {"k_nm": (-0.1, 0.1)}

    def linear_names(self):
        return ["k_nm"]

    def force_terms(self, ctx, nl):
        col = np.zeros(ctx.motion.theta_h_deg.shape + (6,))
        col[..., 3] = np.sin(np.radians(ctx.motion.theta_h_deg))
        return Terms(["k_nm"], [col], [ALL_CHANNELS])

    def hint(self, ev, params):
        return "tx follows the hip angle"


@pytest.fixture
def hip_spring():
    library.register_effect(HipSpring)
    yield HipSpring
    library.unregister_effect(HipSpring.name)


# ---------------------------------------------------------------------- structure
def _imports(path: Path) -> set[str]:
    """Every workbench.diagnose module ``path`` imports, at module level or inside functions."""
    mod = "workbench." + ".".join(path.relative_to(ROOT / "workbench").with_suffix("").parts)
    pkg = mod.rsplit(".", 1)[0] if path.name != "__init__.py" else mod
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(pkg.split(".")[: len(pkg.split(".")) - node.level + 1] + ([base] if base else []))
            out.add(base)
            out |= {f"{base}.{a.name}" for a in node.names}
    return {m for m in out if m.startswith("workbench.diagnose.")}


def _modules() -> dict[str, Path]:
    return {"workbench." + ".".join(p.relative_to(ROOT / "workbench").with_suffix("").parts): p
            for p in PKG.rglob("*.py") if p.name != "__init__.py"}


def test_diagnose_package_has_no_import_cycle():
    mods = _modules()
    graph = {m: sorted(_imports(p) & set(mods)) for m, p in mods.items()}
    assert "workbench.diagnose.effects.base" in graph["workbench.diagnose.effects.servo"]
    assert not graph["workbench.diagnose.effects.base"].count("workbench.diagnose.library")
    state: dict[str, int] = {}

    def visit(m, path):
        state[m] = 1
        for n in graph[m]:
            if state.get(n) == 1:
                raise AssertionError("import cycle: " + " -> ".join(path[path.index(n):] + [n]))
            if n not in state:
                visit(n, path + [n])
        state[m] = 2

    for m in graph:
        if m not in state:
            visit(m, [m])


@pytest.mark.slow  # 4.9 s of CPU idle: one fresh interpreter per module (29 Nov 2026)
def test_every_module_imports_first_in_a_fresh_interpreter():
    names = sorted(_modules())
    code = textwrap.dedent(f"""
        import importlib, sys
        for name in {names!r}:
            for k in [k for k in sys.modules if k.startswith("workbench")]:
                del sys.modules[k]
            importlib.import_module(name)
        from workbench.diagnose.library import registry
        print(len(registry()))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]
    assert int(out.stdout.split()[-1]) >= 19


def _constants(path: Path) -> list[str]:
    """String constants of a module, docstrings left out (f-string parts included)."""
    tree = ast.parse(path.read_text())
    docs = {id(n.body[0].value) for n in ast.walk(tree)
            if isinstance(n, (ast.Module, ast.FunctionDef, ast.ClassDef, ast.AsyncFunctionDef)) and n.body
            and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
    return [n.value for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs]


@pytest.mark.parametrize("module", GENERIC)
def test_the_loop_never_names_an_effect_or_its_parameters(module):
    reg = library.registry()
    words = set(reg)
    for cls in reg.values():
        words |= {p.name for p in cls.search} | set(cls.location_params)
    words |= {"tau_s", "epsilon", "tone_hz", "x_", "aliases"}
    found = []
    for s in _constants(PKG / module):
        for w in words:
            if w in s.replace("-", "_").split() or s == w or f"{w}." in s or f'"{w}"' in s:
                found.append((w, s))
    assert not found, f"{module} names effects: {found}"


def test_pyproject_lists_every_in_tree_effect_as_an_entry_point():
    doc = tomllib.loads((ROOT / "pyproject.toml").read_text())
    eps = doc["project"]["entry-points"]["workbench.effects"]
    in_tree = {cls.name: f"{cls.__module__}:{cls.__name__}" for _, cls in library._in_tree()}
    assert eps == in_tree


# ------------------------------------------------------------------------- the table
def _fake_distribution(root: Path, name: str, entries: dict[str, str]) -> None:
    """A distribution's metadata on ``root`` (what pip writes), declaring ``workbench.effects`` entry points."""
    info = root / f"{name}-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    body = "".join(f"{k} = {v}\n" for k, v in entries.items())
    (info / "entry_points.txt").write_text(f"[workbench.effects]\n{body}")


def test_an_installed_plugin_is_found_through_its_entry_point(tmp_path, monkeypatch):
    _fake_distribution(tmp_path, "lab_effects", {"hip_spring": f"{__name__}:HipSpring",
                                                  "servo_lag": "workbench.diagnose.effects_rig:ServoLag"})
    monkeypatch.syspath_prepend(str(tmp_path))
    library.refresh()
    try:
        reg = library.registry()
        assert reg["hip_spring"] is HipSpring
        # a stale entry point of an in-tree effect (an old module path) does not hide the in-tree class
        assert reg["servo_lag"].__module__ == "workbench.diagnose.effects.servo"
        e = library.make_effect("hip_spring")
        assert e.get_feature_names() == ["hip_spring.k_nm  [tx += k_nm sin(theta_h)]"]
        assert "hip_spring" in library.default_library().names()
    finally:
        monkeypatch.undo()
        library.refresh()
    assert "hip_spring" not in library.registry()


def test_a_broken_plugin_is_a_one_line_error_naming_it(tmp_path, monkeypatch):
    _fake_distribution(tmp_path, "broken_effects", {"wobble": "no_such_module_here:Wobble"})
    monkeypatch.syspath_prepend(str(tmp_path))
    library.refresh()
    try:
        with pytest.raises(ModelError, match=r"effect plug-in 'wobble' does not load .*no_such_module_here"):
            library.registry()
    finally:
        monkeypatch.undo()
        library.refresh()


def test_one_name_one_class(hip_spring):
    class Impostor(HipSpring):
        pass

    with pytest.raises(ModelError, match="registered already"):
        library.register_effect(Impostor)
    with pytest.raises(ModelError, match="unknown effect 'nope'"):
        library.make_effect("nope")
    with pytest.raises(ModelError, match="bad options"):
        library.make_effect("link_drag", {"x_mm": 3})


def test_options_round_trip_through_the_table():
    for name in library.registry():
        e = library.default_library([name], link_x_m=0.02, link_quadrature=3, circulatory_c_r=0.9)[name]
        again = library.make_effect(name, library.effect_options(e))
        assert again.options() == e.options(), name
    assert library.default_library(["link_drag"])["link_drag"].options() == {"x_m": 0.01, "quadrature": 4}
    assert library.default_library(["circulatory_lag"], circulatory_c_r=0.9)["circulatory_lag"].c_r == 0.9


# ------------------------------------------------------------------- the loop
@pytest.mark.slow
def test_a_new_effect_is_fitted_and_named_by_the_loop(hip_spring, tmp_path):
    from diag_helpers import campaign
    from planting import copy_campaign

    from workbench.diagnose.loop import DiagnoseSettings, LibrarySettings, diagnose
    from workbench.hydro.ef import EmpiricalFormula
    from workbench.ingest import ingest_campaign

    k = 0.004  # N m: a cable spring's moment, a few times the tx noise

    def plant(lc, mo, run):  # this test's formula, on the raw files: tx += k sin(commanded hip angle)
        th = np.interp(lc["t_ctrl"], mo["time_s"], mo["hfe_cmd_deg"])
        lc["tx_nm"] = lc["tx_nm"] + k * np.sin(np.radians(th))

    src = campaign(tmp_path / "src", (), "ef", n_sets=8)
    planted = copy_campaign(src, tmp_path / "hip-spring", [plant])
    frame = ingest_campaign(planted, params={"workers": 1}).frame
    settings = DiagnoseSettings(library=LibrarySettings(effects=("hip_spring", "sensor_drift", "added_mass_error")))
    d = diagnose(frame, EmpiricalFormula(), "ef", settings)
    found = {e.name: e for e in d.effects}
    assert list(found) == ["hip_spring"], [(e.name, e.params) for e in d.effects]
    e = found["hip_spring"]
    assert e.params["k_nm"] == pytest.approx(k, rel=0.1)
    assert e.evidence.startswith("tx follows the hip angle")
    assert e.heldout_mse_reduction_by_channel["tx_nm"] > 0.5
    # the augmented model names and rebuilds it through the same table
    doc = d.augmented.to_json() if hasattr(d.augmented, "to_json") else None
    assert doc is None or any(x["name"] == "hip_spring" for x in doc["effects"])


def test_input_effects_act_on_an_expensive_models_output_through_their_hooks():
    """The surrogate search asks input effects how they act on a model's output (no names in the chain).

    A lag of the output equals a lag of the input to first order in tau, and a blocked flow by
    the quadratic through three flows: the surrogate is much closer to the exact design than the
    plain model is.
    """
    from workbench.diagnose.chain import Active, Configuration, build_design
    from workbench.diagnose.effects.blockage import TunnelBlockage
    from workbench.diagnose.effects.servo import ServoLag
    from workbench.hydro.ef import EmpiricalFormula
    from workbench.hydro.motion import JointSinusoid, LegMotion

    t = np.arange(0, 6, 1 / 65)
    rows = [JointSinusoid(10, -100, 80, -20 - 10 * i, 0.4 + 0.1 * i, 1.0).motion(t, 0.2) for i in range(2)]
    motion = LegMotion(rows[0].dt_s, *(np.concatenate([getattr(r, f) for r in rows]) for f in
                                       ("theta_h_deg", "theta_k_deg", "omega_h_dps", "omega_k_dps", "flow_speed_mps",
                                        "alpha_h_dps2", "alpha_k_dps2")))

    class Batch:
        def __init__(self, m):
            self.motion, self.dt_s = m, m.dt_s
            self.time_s = np.broadcast_to(np.arange(m.theta_h_deg.shape[1]) * m.dt_s, m.theta_h_deg.shape)

    rs, ef = Batch(motion), EmpiricalFormula()
    plain = build_design(ef, rs, Configuration()).base
    for nl_lag, nl_blk in (({"tau_s": 0.03}, None), (None, {"epsilon": 0.1}), ({"tau_s": 0.03}, {"epsilon": 0.1})):
        cfg = Configuration()
        if nl_lag:
            cfg = cfg.with_effect(Active(ServoLag(), nl_lag))
        if nl_blk:
            cfg = cfg.with_effect(Active(TunnelBlockage(), nl_blk))
        exact = build_design(ef, rs, cfg).base
        sur = build_design(ef, rs, cfg, surrogate=True).base
        skip = 65  # the lag's start-up
        err = np.sqrt(np.mean((sur - exact)[:, skip:] ** 2))
        moved = np.sqrt(np.mean((plain - exact)[:, skip:] ** 2))
        assert 0 < err < 0.2 * moved, (nl_lag, nl_blk, err, moved)  # the surrogate ran, and is close


def test_an_effects_own_options_come_from_the_library_section():
    from workbench.diagnose.loop import DiagnoseSettings

    s = DiagnoseSettings.from_mapping({"library": {"effects": ["wagner_lag", "link_drag"],
                                                   "options": {"wagner_lag": {"time_scale": 1.2},
                                                               "link_drag": {"x_m": 0.02}}}})
    lib = library.default_library(list(s.library.effects), s.library.link_x_m, s.library.link_quadrature, 0.7,
                                  options=s.library.options)
    assert lib["wagner_lag"].time_scale == 1.2
    assert lib["link_drag"].options() == {"x_m": 0.02, "quadrature": 4}  # its own option wins over link_x_m
    with pytest.raises(ModelError, match=r"unknown effect\(s\) \['wagner_lags'\]"):
        library.default_library(options={"wagner_lags": {"time_scale": 1.2}})
