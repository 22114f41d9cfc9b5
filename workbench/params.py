"""Settings from pipeline parameter files: one section of a YAML file -> one frozen settings dataclass.

Every verb reads its knobs the same way::

    from workbench.params import load_settings
    settings = load_settings(DragFitSettings, args.params, "fit", default="pipelines/drag.yaml")

:func:`read_section` finds the file (an explicit ``--params`` file, else the project's default file,
else built-in defaults) and returns one section, addressed by a dotted key (``optimize.nsga2``).
:func:`build` turns a mapping into a frozen dataclass: nested dataclasses are built from nested
mappings, YAML's ints become floats where a float is declared, lists become tuples (a list left
empty, i.e. null, is empty), ``Optional``, ``Literal`` choices, lists, tuples and mappings are
checked, and an unknown key is refused with a
:class:`~workbench.errors.ParamsError` naming the file, the key path (``diagnose.fit.surrogate_serch``),
the nearest allowed key and all of them. The dataclass's own ``__post_init__`` checks (ranges,
combinations) run as usual; a ``ValueError`` or ``TypeError`` they raise is reported the same way.
"""

from __future__ import annotations

import copy
import dataclasses
import datetime as _dt
import difflib
import functools
import math
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

from workbench.errors import ParamsError, WorkbenchError

T = TypeVar("T")

__all__ = ["build", "load_settings", "read_document", "read_section", "set_dotted", "suggest"]


def suggest(key: str, allowed: Sequence[str]) -> str:
    """``"did you mean 'x'? allowed: a, b"`` for an unknown ``key`` (the allowed list alone when nothing is near)."""
    near = difflib.get_close_matches(key, list(allowed), n=1, cutoff=0.6)
    listed = ", ".join(allowed) if allowed else "none"
    return (f"did you mean '{near[0]}'? " if near else "") + f"allowed: {listed}"


def _resolve_file(path: str | Path | None, default: str | Path | None) -> Path | None:
    """The parameter file to read, or None for built-in defaults (no file given and no default file).

    An explicit relative path is taken from the working directory, else from the project root;
    the default file always from the project root.
    """
    from workbench.project import project_root

    if path is None and default is None:
        return None
    if path is None:
        p = Path(default)
        p = p if p.is_absolute() else project_root() / p
        return p if p.is_file() else None  # the default file is optional: built-in defaults apply
    p = Path(path)
    if not p.is_absolute() and not p.exists():
        p = project_root() / p
    if p.is_file():
        return p
    if default is not None and str(path) == str(default):
        return None  # the default, spelled out by argparse
    raise ParamsError("parameter file not found", path=p)


@functools.lru_cache(maxsize=32)
def _load_yaml(path: str, mtime: float, size: int) -> Any:
    import yaml

    try:
        with open(path, encoding="utf-8") as fh:
            return yaml.safe_load(fh)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else None
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ParamsError(f"not valid YAML: {problem}", path=path, where=where) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ParamsError(f"cannot read parameter file: {exc}", path=path) from None


def read_document(path: str | Path) -> Any:
    """A whole parameter file, parsed (an empty file: ``{}``); a missing file or bad YAML is a ParamsError."""
    p = _resolve_file(path, None)
    st = p.stat()
    doc = _load_yaml(str(p), st.st_mtime, st.st_size)
    return {} if doc is None else copy.deepcopy(doc)  # the parsed file is cached: callers get their own copy


#: a section's key naming another parameter file whose same section it changes (``extends: gait.yaml``)
EXTENDS = "extends"


def _merged(base: Mapping, changes: Mapping) -> dict:
    """``base`` with ``changes`` on top: nested mappings merged key by key, any other value replaced."""
    out = dict(base)
    for k, v in changes.items():
        out[k] = _merged(out[k], v) if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) else v
    return out


def _extended(node: Mapping, section: str, path: Path, depth: int = 0) -> dict:
    """A section with ``extends: FILE``: FILE's same section with this one's other keys on top.

    FILE is taken relative to this file's folder (then the project root); it may extend another
    file in turn (up to 8 deep). A missing file or section is a ParamsError naming this file.
    """
    from workbench.project import project_root

    ref = node[EXTENDS]
    if not isinstance(ref, str) or not ref or depth > 8:
        raise ParamsError("must name another parameter file (a path)" if depth <= 8 else "files extend each other "
                          "in a loop", path=path, where=f"{section}.{EXTENDS}")
    base_path = path.parent / ref
    if not base_path.is_file():
        base_path = project_root() / ref
    if not base_path.is_file():
        raise ParamsError(f"the file it extends, {ref}, does not exist", path=path, where=f"{section}.{EXTENDS}")
    st = base_path.stat()
    base_doc = _load_yaml(str(base_path), st.st_mtime, st.st_size) or {}
    base = base_doc.get(section) if isinstance(base_doc, Mapping) else None
    if not isinstance(base, Mapping):
        raise ParamsError(f"{ref} has no section '{section}' to extend", path=path, where=f"{section}.{EXTENDS}")
    if EXTENDS in base:
        base = _extended(base, section, base_path, depth + 1)
    return _merged(base, {k: v for k, v in node.items() if k != EXTENDS})


def read_section(path: str | Path | None, section: str, *, default: str | Path | None = None,
                 required: bool = True) -> tuple[dict, str | None]:
    """One section of a parameter file as a plain dict, and the file it came from (None: built-in defaults).

    ``path`` is the ``--params`` file (None: ``default``). When ``path`` is None or equal to
    ``default`` and that file does not exist, the section is empty (built-in defaults apply); an
    explicit file that does not exist is an error. ``section`` may be dotted (``optimize.nsga2``).
    A file without the section is an error when ``required`` (the file was probably meant for
    another verb), else an empty section; a section written as ``null`` is empty. A top-level
    section with ``extends: FILE`` is FILE's same section with this one's keys on top (nested
    mappings merged): a variant file holds only what it changes (pipelines/gait_sides.yaml).
    """
    p = _resolve_file(path, default)
    if p is None:
        return {}, None
    st = p.stat()
    doc = _load_yaml(str(p), st.st_mtime, st.st_size)
    if doc is None:
        doc = {}
    top = section.split(".")[0]
    if isinstance(doc, Mapping) and isinstance(doc.get(top), Mapping) and EXTENDS in doc[top]:
        doc = {**doc, top: _extended(doc[top], top, p)}
    node: Any = doc
    walked: list[str] = []
    for part in section.split("."):
        if not isinstance(node, Mapping):
            raise ParamsError("must be a mapping of settings", path=p, where=".".join(walked) or None)
        if part not in node:
            if not required:
                return {}, str(p)
            where = ".".join(walked) or None
            raise ParamsError(f"no section '{'.'.join([*walked, part])}' in parameter file", path=p, where=where,
                              hint=suggest(part, [str(k) for k in node]).replace("allowed:", "sections:"))
        node = node[part]
        walked.append(part)
    if node is None:
        return {}, str(p)
    if not isinstance(node, Mapping):
        raise ParamsError(f"must be a mapping of settings, not {type(node).__name__}", path=p, where=section)
    return copy.deepcopy(dict(node)), str(p)  # the parsed file is cached: callers get their own copy


def load_settings(cls: type[T], path: str | Path | None, section: str, *, default: str | Path | None = None,
                  overrides: Mapping[str, Any] | None = None, required: bool = True) -> T:
    """``cls`` built from a file's section (see :func:`read_section`), with ``overrides`` (CLI flags) on top.

    Overrides whose value is None are ignored, so argparse defaults of None leave the file's value.
    """
    raw, source = read_section(path, section, default=default, required=required)
    raw.update({k: v for k, v in (overrides or {}).items() if v is not None})
    return build(cls, raw, key=section, path=source)


def set_dotted(doc: dict, key: str, value: Any, *, section: str, path: str | Path | None = None) -> None:
    """Set ``doc[a][b][c] = value`` for a dotted ``key`` (``--set a.b.c=...``), making sections as needed.

    Whether the key exists is :func:`build`'s to say (it names the key path and the allowed keys);
    here only a part that is already set to something other than a section is an error.
    """
    node = doc
    parts = key.strip().split(".")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
        if not isinstance(node, dict):
            raise ParamsError(f"'{part}' is not a section, cannot set '{key}'", path=path, where=f"{section}.{key}")
    node[parts[-1]] = value


def build(cls: type[T], raw: Mapping[str, Any] | None, *, key: str, path: str | Path | None = None) -> T:
    """A frozen ``cls`` from a mapping; unknown keys, wrong types and failed checks are :class:`ParamsError`.

    ``key`` is the section's key path, used in messages (``diagnose.fit``); ``path`` the file.
    """
    if raw is None:
        raw = {}
    if isinstance(raw, cls):
        return raw
    if not isinstance(raw, Mapping):
        raise ParamsError(f"must be a mapping of settings, not {_kind(raw)}", path=path, where=key)
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    hints = _hints(cls)
    kwargs = {}
    for name, value in raw.items():
        if name not in names:
            raise ParamsError(f"unknown setting '{name}'", path=path, where=f"{key}.{name}",
                              hint=suggest(str(name), names))
        kwargs[name] = _coerce(value, hints.get(name, Any), f"{key}.{name}", path)
    try:
        return cls(**kwargs)
    except ParamsError as exc:
        if exc.path is None:
            raise ParamsError(exc.fault, path=path, where=exc.where or key, hint=exc.hint) from None
        raise
    except WorkbenchError as exc:  # a __post_init__ check written before ParamsError existed
        raise ParamsError(exc.fault, path=exc.path or path, where=key, hint=exc.hint) from None
    except (ValueError, TypeError) as exc:
        raise ParamsError(str(exc), path=path, where=key) from None


@functools.lru_cache(maxsize=256)
def _hints(cls: type) -> dict[str, Any]:
    try:
        return typing.get_type_hints(cls)
    except Exception:  # an annotation that cannot be resolved: values pass through unchecked
        return {}


def _kind(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true/false"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, (list, tuple)):
        return "a list"
    return f"{type(value).__name__} {value!r}"


def _describe(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if tp is type(None):
        return "null"
    if origin is typing.Literal:
        return "one of " + ", ".join(repr(a) for a in typing.get_args(tp))
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_describe(a) for a in typing.get_args(tp))
    if origin in (tuple, list, Sequence) or tp in (tuple, list):
        return "a list"
    if origin in (dict, Mapping) or tp in (dict, Mapping):
        return "a mapping"
    if dataclasses.is_dataclass(tp):
        return "a mapping"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(tp, str(tp))


def _bad(value: Any, tp: Any, where: str, path) -> ParamsError:
    return ParamsError(f"must be {_describe(tp)}, got {_kind(value)}", path=path, where=where)


def _coerce(value: Any, tp: Any, where: str, path: str | Path | None) -> Any:
    """``value`` as type ``tp`` (YAML int -> float, list -> tuple, nested mapping -> dataclass)."""
    if tp is Any or tp is object:
        return value
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return _coerce_union(value, tp, where, path)
    if origin is typing.Literal:
        return _coerce_literal(value, tp, where, path)
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return build(tp, value, key=where, path=path)
    if tp in (bool, int, float, str):
        return _coerce_scalar(value, tp, where, path)
    if origin in (tuple, list, Sequence) or tp in (tuple, list):
        return _coerce_sequence(value, tp, where, path)
    if origin in (dict, Mapping) or tp in (dict, Mapping):
        if not isinstance(value, Mapping):
            raise _bad(value, tp, where, path)
        args = typing.get_args(tp)
        vt = args[1] if len(args) == 2 else Any
        return {k: _coerce(v, vt, f"{where}.{k}", path) for k, v in value.items()}
    return value


def _coerce_union(value: Any, tp: Any, where: str, path) -> Any:
    args = typing.get_args(tp)
    if value is None and type(None) in args:
        return None
    options = [a for a in args if a is not type(None)]
    for arg in options:
        try:
            return _coerce(value, arg, where, path)
        except ParamsError:
            if len(options) == 1:
                raise
    raise _bad(value, tp, where, path)


def _coerce_literal(value: Any, tp: Any, where: str, path) -> Any:
    args = typing.get_args(tp)
    if any(value == a and type(value) is type(a) for a in args):
        return value
    near = difflib.get_close_matches(str(value), [str(a) for a in args], n=1, cutoff=0.6)
    raise ParamsError(f"must be one of {', '.join(repr(a) for a in args)}, got {value!r}", path=path,
                      where=where, hint=f"did you mean '{near[0]}'?" if near else None)


def _coerce_scalar(value: Any, tp: type, where: str, path) -> Any:
    """``value`` as the scalar type ``tp`` (bool, int, float or str), else a ParamsError naming what it got."""
    out = _scalar(value, tp)
    if out is None:
        raise _bad(value, tp, where, path)
    return out


def _scalar(value: Any, tp: type) -> Any:
    """``value`` read as ``tp``, None when it cannot be (YAML's true/false is not a number)."""
    if tp is bool or tp is str:
        return _flag_or_text(value, tp)
    if isinstance(value, bool):
        return None
    if tp is int:
        return _integer(value)
    return _number(value)


def _flag_or_text(value: Any, tp: type) -> Any:
    """A bool or str as itself; a date as its ISO text when a str is wanted; else None."""
    if isinstance(value, tp):
        return value
    if tp is str and isinstance(value, _dt.date):  # YAML reads 2025-03-14 as a date
        return value.isoformat()
    return None


def _integer(value: Any) -> int | None:
    """An int, or a float with no fractional part, as an int; else None."""
    if isinstance(value, int) or (isinstance(value, float) and value.is_integer()):
        return int(value)
    return None


def _number(value: Any) -> float | None:
    """An int or float as a float, a numeric string too (YAML 1.1 reads 1e-5, no dot, as a string); else None."""
    if isinstance(value, (int, float)):
        return float(value)
    if isinstance(value, str):
        try:
            out = float(value)
        except ValueError:
            return None
        return None if math.isnan(out) else out
    return None


def _coerce_sequence(value: Any, tp: Any, where: str, path) -> Any:
    origin = typing.get_origin(tp)
    if value is None and not (origin is tuple and typing.get_args(tp) and typing.get_args(tp)[-1] is not Ellipsis):
        value = []  # ``effects:`` left empty in YAML is null: an empty list
    if not isinstance(value, (list, tuple)):
        raise _bad(value, tp, where, path)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is tuple and args and args[-1] is not Ellipsis:
        if len(value) != len(args):
            raise ParamsError(f"must be a list of {len(args)} values, got {len(value)}", path=path, where=where)
        return tuple(_coerce(v, a, f"{where}[{i}]", path) for i, (v, a) in enumerate(zip(value, args, strict=True)))
    item = args[0] if args else Any
    items = [_coerce(v, item, f"{where}[{i}]", path) for i, v in enumerate(value)]
    return items if (origin is list or tp is list) else tuple(items)
