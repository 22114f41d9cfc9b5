"""Which workbench source files a DVC stage's command can run, derived from the imports (issue 15.1).

    python tests/stage_deps.py            # per stage: the files its deps in dvc.yaml miss
    python tests/stage_deps.py --fix      # rewrite the stages' workbench/ deps in dvc.yaml from the imports

A stage runs ``workbench <verb> ...``: the entry point ``workbench/cli.py`` imports every verb module
to build its parser, but only the stage's own verb does work. So a stage's code is the closure of

- ``workbench/cli.py`` and the stage's verb module ``workbench/commands/<verb>.py``, following
  every import in them, module level and inside functions (a superset: a function-level import
  may not run, but it can), and
- every module named by a whole string in a sequence literal or a call of a reached module
  (``_PLUGIN_MODULES = ("workbench.learn.plugin", ...)``, ``import_module("workbench.x")``):
  plug-in tables import such modules by name; a package named so brings in all its modules
  (a package scan). Dict keys naming modules are lookups, not imports. A ``"module:function"`` loader target is not
  followed: it runs only when that model is asked for, and the stage asking for it names the
  package in its deps;

with the other verb modules left out of cli.py's imports (cli.py only calls their ``register``, the
argument parsers), but followed where the stage's own verb module imports them.
A package's ``__init__.py`` counts when any of its modules is imported.
"""
from __future__ import annotations

import ast
import re
import sys
from functools import lru_cache
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "workbench"
MODULE_STRING = re.compile(r"workbench(?:\.[A-Za-z_][A-Za-z0-9_]*)+")
VERB = re.compile(r"\bworkbench\s+([a-z][a-z-]*)")


def module_file(name: str) -> Path | None:
    """The file of a dotted ``workbench`` module name (module or package), or None."""
    parts = name.split(".")
    if parts[0] != "workbench":
        return None
    while parts:
        base = ROOT.joinpath(*parts)
        if base.with_suffix(".py").is_file():
            return base.with_suffix(".py")
        if (base / "__init__.py").is_file():
            return base / "__init__.py"
        parts = parts[:-1]  # "workbench.x.y" where y is an attribute of module x
    return None


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _named_modules(node: ast.AST, pkg: list[str]) -> set[str]:
    """Module names one AST node imports or names (imports, module-name strings, plug-in tables)."""
    if isinstance(node, ast.Import):
        return {a.name for a in node.names}
    if isinstance(node, ast.ImportFrom):
        if node.level:
            base = pkg[: len(pkg) - node.level + 1]
            mod = ".".join(base + ([node.module] if node.module else []))
        else:
            mod = node.module or ""
        return {mod} | {f"{mod}.{a.name}" for a in node.names}
    if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant) \
            and isinstance(node.value.value, str) and MODULE_STRING.fullmatch(node.value.value):
        return {node.value.value}  # IN_TREE_PACKAGE = "workbench.diagnose.effects" (scanned later)
    if isinstance(node, (ast.Tuple, ast.List, ast.Set, ast.Call)):
        # a plug-in table (a sequence of module names) or import_module("workbench.x"); dict keys
        # naming modules (a lookup table, atomic.py's verbs) are not imports
        items = node.elts if not isinstance(node, ast.Call) else node.args
        return {c.value for c in items if isinstance(c, ast.Constant) and isinstance(c.value, str)
                and MODULE_STRING.fullmatch(c.value)}
    return set()


@lru_cache(maxsize=None)
def direct_imports(path: Path) -> frozenset[Path]:
    tree = ast.parse(path.read_text(), filename=str(path))
    pkg = module_name(path).split(".")
    if path.name != "__init__.py":
        pkg = pkg[:-1]
    names: set[str] = set()
    for node in ast.walk(tree):
        names.update(_named_modules(node, pkg))
    files = set()
    for n in list(names):
        f = module_file(n)
        if f is not None and f.name == "__init__.py" and n.replace(".", "/") == str(f.parent.relative_to(ROOT)):
            if n not in imported_names(tree):
                files.update(f.parent.rglob("*.py"))  # named by a string: scanned at run time
    for n in names:
        f = module_file(n)
        if f is not None:
            files.add(f)
            # importing a.b.c runs a/__init__.py and a/b/__init__.py
            parent = f.parent
            while parent != ROOT and (parent / "__init__.py").is_file():
                files.add(parent / "__init__.py")
                parent = parent.parent
    return frozenset(files)


def imported_names(tree: ast.AST) -> set[str]:
    """Module names of import statements (not strings)."""
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            out.add(node.module)
    return out


def closure(starts: list[Path], skip: set[Path]) -> set[Path]:
    seen: set[Path] = set()
    todo = list(starts)
    while todo:
        f = todo.pop()
        if f in seen:
            continue
        seen.add(f)
        todo.extend(g for g in direct_imports(f) if g not in seen and g not in skip)
    return seen


def verb_module(cmd: str) -> Path | None:
    m = VERB.search(cmd)
    if not m:
        return None
    f = PKG / "commands" / (m.group(1).replace("-", "_") + ".py")
    return f if f.is_file() else None


def stage_code(cmd: str) -> set[Path]:
    verb = verb_module(cmd)
    if verb is None:
        return set()
    others = {p for p in (PKG / "commands").glob("*.py") if p not in (verb, PKG / "commands" / "__init__.py",
                                                                          PKG / "commands" / "_help.py")}
    # cli.py's own imports, but not through the other verbs; the verb's own imports in full (a verb
    # module may use another's helpers: diagnose -> diagnose_trials -> simulate)
    return closure([PKG / "cli.py"], skip=others | {verb}) | closure([verb], skip=set())


def dvc_stages(dvc_yaml: Path = ROOT / "dvc.yaml") -> dict[str, dict]:
    doc = yaml.safe_load(dvc_yaml.read_text())
    out = {}
    for name, st in doc["stages"].items():
        if "foreach" in st:
            st = st["do"]
        out[name] = st
    return out


def dep_paths(stage: dict) -> list[Path]:
    out = []
    for d in stage.get("deps", []) or []:
        out.append(ROOT / (d if isinstance(d, str) else next(iter(d))))
    return out


def covered(f: Path, deps: list[Path]) -> bool:
    return any(f == d or d in f.parents for d in deps)


def missing_deps() -> dict[str, list[str]]:
    out = {}
    for name, st in dvc_stages().items():
        code = stage_code(st["cmd"] if isinstance(st["cmd"], str) else " ".join(st["cmd"]))
        deps = dep_paths(st)
        miss = sorted(str(f.relative_to(ROOT)) for f in code if not covered(f, deps))
        if miss:
            out[name] = miss
    return out


def minimal_cover(files: set[Path], share: float = 0.6) -> list[str]:
    """Few paths that cover ``files``: a package folder when at least ``share`` of its modules are
    in (a superset: DVC then also reruns on its other modules), else the files one by one."""
    out: list[str] = []
    pending = set(files)

    def visit(folder: Path) -> None:
        mods = set(folder.rglob("*.py"))
        if mods and folder != PKG and len(mods & files) >= share * len(mods):
            out.append(str(folder.relative_to(ROOT)))
            pending.difference_update(mods)
            return
        for sub in sorted(p for p in folder.iterdir() if p.is_dir() and (p / "__init__.py").is_file()):
            visit(sub)

    visit(PKG)
    out += sorted(str(f.relative_to(ROOT)) for f in pending)
    return sorted(out)


def fix_dvc_yaml(path: Path = ROOT / "dvc.yaml") -> int:
    """Rewrite each stage's ``workbench/`` deps in dvc.yaml from the imports (other lines untouched)."""
    stages = dvc_stages(path)
    lines = path.read_text().splitlines()
    out, stage, i, changed = [], None, 0, 0
    while i < len(lines):
        line = lines[i]
        m = re.match(r"^  ([A-Za-z0-9_]+):\s*$", line)
        if m:
            stage = m.group(1)
        d = re.match(r"^(\s+)deps:\s*$", line)
        if d and stage in stages:
            out.append(line)
            i += 1
            block = []
            while i < len(lines) and re.match(r"^" + d.group(1) + r"  - ", lines[i]):
                block.append(lines[i])
                i += 1
            keep = [b for b in block if not b.strip().startswith("- workbench/")]
            cmd = stages[stage]["cmd"]
            code = stage_code(cmd if isinstance(cmd, str) else " ".join(cmd))
            new = keep + [f"{d.group(1)}  - {p}" for p in minimal_cover(code)] if code else block
            changed += new != block
            out += new
            continue
        out.append(line)
        i += 1
    path.write_text("\n".join(out) + "\n")
    return changed


if __name__ == "__main__":
    if "--fix" in sys.argv:
        print(f"dvc.yaml: workbench deps rewritten in {fix_dvc_yaml()} stage(s)")
    miss = missing_deps()
    for stage, files in miss.items():
        print(f"{stage}:")
        for f in files:
            print(f"  - {f}")
    sys.exit(1 if miss else 0)
