"""The rules of docs/architecture.md, read from the doc itself, checked on the source with ast.

The doc's *checked* tables are parsed here, so a rule change is a doc change: a new package needs
a layer, an upward import needs a written reason, a module that touches files or imports a heavy
library at its top needs a row, and a row the code no longer needs must go.
"""

from __future__ import annotations

import ast
import fnmatch
import functools
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "workbench"
DOC = ROOT / "docs" / "architecture.md"
HEAVY = ("torch", "lightning", "mlflow", "optuna", "cv2", "pymoo")
IO_ATTRS = {"read_text", "write_text", "read_bytes", "write_bytes", "mkdir", "unlink", "iterdir", "glob", "rglob"}
IO_CALLS = {("pl", "read_parquet"), ("pl", "read_csv"), ("json", "dump"), ("json", "load"), ("torch", "save"),
            ("torch", "load"), ("np", "save"), ("np", "load"), ("shutil", "rmtree"), ("pq", "write_table")}


def _table(title: str, allow_empty: bool = False) -> list[list[str]]:
    """Rows of the first markdown table under the heading ``title`` (cells stripped of backticks).

    ``allow_empty``: a table of a header alone is fine (a list of debts, all paid).
    """
    text = DOC.read_text(encoding="utf-8")
    m = re.search(rf"^#+ {re.escape(title)}\s*$", text, flags=re.M)
    assert m, f"{DOC}: no section '{title}'"
    rows = []
    for line in text[m.end():].splitlines():
        if line.startswith("#"):
            break
        if line.startswith("|") and not re.match(r"^\|[-| ]+\|$", line):
            rows.append([c.strip().strip("`") for c in line.strip().strip("|").split("|")])
        elif rows and not line.strip():
            break
    assert rows and (allow_empty or len(rows) > 1), f"{DOC}: empty table under '{title}'"
    return rows[1:]  # without the header


def _layers() -> dict[str, int]:
    out = {}
    for layer, names in _table("Layers (checked)"):
        for name in names.split(","):
            out[name.strip()] = int(layer)
    return out


def _unit(path: Path) -> str:
    """The top-level package or module a file belongs to (``gait``, ``errors``, ``__init__``)."""
    rel = path.relative_to(PKG).parts
    return rel[0] if len(rel) > 1 else rel[0].removesuffix(".py")


def _sources() -> list[Path]:
    return sorted(p for p in PKG.rglob("*.py") if "__pycache__" not in p.parts)


def _rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


@functools.lru_cache(maxsize=None)
def _tree(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"))


@functools.lru_cache(maxsize=None)
def _imports(path: Path, module_parts: tuple[str, ...] | None = None) -> list[tuple[str, bool]]:
    """(module, at_top) for every absolute and relative import of a file, lazy ones included."""
    tree = _tree(path)
    top = {id(n) for n in tree.body}
    pkg_parts = (module_parts or path.relative_to(ROOT).with_suffix("").parts)[:-1]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, id(node) in top) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = pkg_parts[: len(pkg_parts) - node.level + 1]
                base = ".".join([*parent, base] if base else parent)
            out.append((base, id(node) in top))
            out += [(f"{base}.{a.name}", id(node) in top) for a in node.names]
    return out


def _workbench_target(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "workbench" and len(parts) > 1 else None


def test_every_package_and_module_has_a_layer():
    layers = _layers()
    units = {_unit(p) for p in _sources()}
    missing = sorted(units - set(layers))
    assert not missing, f"{DOC}: give these a row in 'Layers (checked)': {missing}"


def _violations(src: str, rel: str, imports, layers: dict[str, int]) -> set[tuple[str, str]]:
    """Imports of the unit ``src`` (file ``rel``) into its own layer or a higher one."""
    mine = layers[src]
    found = set()
    if mine == max(layers.values()):
        return found  # the entry layer may import anything
    for module, _ in imports:
        tgt = _workbench_target(module)
        if tgt is None or tgt == src or tgt not in layers:
            continue
        theirs = layers[tgt]
        if not (theirs == 0 or (mine > 0 and theirs < mine)):
            found.add((rel, ".".join(module.split(".")[:3])))
    return found


def _upward_imports() -> set[tuple[str, str]]:
    layers = _layers()
    found = set()
    for path in _sources():
        found |= _violations(_unit(path), _rel(path), _imports(path), layers)
    return found


def test_no_package_imports_its_own_layer_or_a_higher_one():
    known = {(a, b) for a, b, *_ in _table("Known upward imports (checked)", allow_empty=True)}
    found = _upward_imports()
    # an import of a module's member (workbench.gait.tabulate.X) is reported at module depth
    new = sorted(f for f in found if not any(f[0] == a and f[1].startswith(b) for a, b in known))
    assert not new, f"imports against the layers of {DOC} (fix them, or list them with a reason): {new}"
    gone = sorted(k for k in known if not any(f[0] == k[0] and f[1].startswith(k[1]) for f in found))
    assert not gone, f"{DOC}: these listed upward imports are gone; delete their rows: {gone}"


def _does_file_io(path: Path) -> bool:
    for node in ast.walk(_tree(path)):
        if not isinstance(node, ast.Call):
            continue
        fn = node.func
        if isinstance(fn, ast.Name) and fn.id == "open":
            return True
        if isinstance(fn, ast.Attribute):
            if isinstance(fn.value, ast.Name) and (fn.value.id, fn.attr) in IO_CALLS:
                return True
            if fn.attr in IO_ATTRS:
                return True
    return False


def test_only_commands_and_the_listed_modules_touch_files():
    listed = {row[0] for row in _table("Who touches files (checked)")}
    doing = {_rel(p) for p in _sources() if p.relative_to(PKG).parts[0] != "commands" and _does_file_io(p)}
    new = sorted(doing - listed)
    assert not new, (f"file I/O outside commands/ in {new}: hand data to the command, or add the module "
                     f"to 'Who touches files' in {DOC} with a reason")
    stale = sorted(m for m in listed - doing if (ROOT / m).exists())
    assert not stale, f"{DOC}: these no longer touch files; delete their rows: {stale}"


def _heavy_at_top(path: Path) -> set[str]:
    return {m.split(".")[0] for m, top in _imports(path) if top and m.split(".")[0] in HEAVY}


def _listed_imports_at_top(path: Path, rel: str, allowed) -> list[str]:
    """Modules of the heavy-libraries list that `path` imports at its top (each loads its library)."""
    bad = []
    for module, top in _imports(path):
        target = module.replace(".", "/") + ".py"
        if top and allowed(target) and (ROOT / target).is_file():
            bad.append(f"{rel}: imports {module} at the top")
    return bad


def test_heavy_libraries_are_imported_at_the_top_only_by_the_listed_modules():
    rows = {row[0]: {x.strip() for x in row[1].split(",")} for row in _table("Heavy libraries (checked)")}

    def allowed(rel: str) -> set[str]:
        return set().union(*(libs for pattern, libs in rows.items() if fnmatch.fnmatch(rel, pattern)))

    bad, stale, seen = [], [], {pattern: set() for pattern in rows}
    for path in _sources():
        rel, heavy = _rel(path), _heavy_at_top(path)
        if heavy - allowed(rel):
            bad.append(f"{rel}: {sorted(heavy - allowed(rel))}")
        for pattern in rows:
            if fnmatch.fnmatch(rel, pattern):
                seen[pattern] |= heavy
        # a module outside the list must not import a listed one at its top (that would load the library)
        if not allowed(rel):
            bad += _listed_imports_at_top(path, rel, allowed)
    for pattern, libs in rows.items():
        exists = any(fnmatch.fnmatch(_rel(p), pattern) for p in _sources())
        if exists and seen[pattern] != libs:
            stale.append(f"{pattern}: imports {sorted(seen[pattern])} at the top, the doc says {sorted(libs)}")
    assert not bad, f"heavy imports at module top (move them into the functions that need them): {bad}"
    assert not stale, f"{DOC}: update 'Heavy libraries': {stale}"


def test_the_cli_with_every_verb_loads_no_heavy_library():
    code = ("import sys\nfrom workbench.cli import build_parser\nbuild_parser()\n"
            f"print(sorted(m for m in sys.modules if m.split('.')[0] in {HEAVY!r}))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]", f"workbench --help loads {proc.stdout.strip()}"


@pytest.mark.parametrize("title", ["Layers (checked)", "Known upward imports (checked)",
                                   "Who touches files (checked)", "Heavy libraries (checked)"])
def test_the_doc_tables_parse_and_name_real_things(title):
    rows = _table(title, allow_empty=title == "Known upward imports (checked)")
    if title == "Layers (checked)":
        names = [n.strip() for _, ns in rows for n in ns.split(",")]
        assert len(names) == len(set(names)), "a package sits in two layers"
        assert {"commands", "contract", "hydro", "errors"} <= set(names)
    elif title == "Known upward imports (checked)":
        assert all((ROOT / r[0]).is_file() for r in rows)
    # rows may name modules another branch has not landed yet: absent files are not checked


def test_the_checker_sees_a_planted_violation(tmp_path):
    """The ast walk finds lazy and relative imports (a checker that sees nothing would pass)."""
    fake = tmp_path / "planted.py"
    fake.write_text("import numpy\nfrom workbench.contract import columns\n\n\ndef f():\n"
                    "    from workbench.gait import run\n    from ..learn import nets\n    from . import ef\n",
                    encoding="utf-8")
    imports = _imports(fake, ("workbench", "hydro", "planted"))
    found = {b for _, b in _violations("hydro", "workbench/hydro/planted.py", imports, _layers())}
    assert found == {"workbench.gait", "workbench.gait.run", "workbench.learn", "workbench.learn.nets"}
    assert ("workbench.gait.run", False) in imports and ("workbench.contract.columns", True) in imports
