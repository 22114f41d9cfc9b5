"""Atomic output that never loses anything: files and folders are built beside their target and swapped in.

Three rules hold for every verb that writes through this module (docs/data-outputs.md):

* **Whole or old.** A file is written to a temporary sibling, fsynced and renamed over its target; a
  folder is built in a hidden sibling and swapped in whole. A kill at any moment leaves either the
  previous output or the new one, never a mix.
* **Never delete what we did not write.** :func:`atomic_dir` replaces an existing folder only when it
  holds this verb's earlier output: a marker file (:data:`MARKER`, written into every folder it swaps
  in) naming the verb, or, for folders written before markers existed, content made only of names the
  verb is known to write (:data:`KNOWN_OUTPUTS`). Anything else is refused with a one-line error.
  Nothing is ever written inside a raw campaign or trials folder (one holding ``campaign.toml`` or
  ``trials.toml``, or anything under one).
* **Nothing left behind.** Temporary names carry the writer's pid (``.<name>.wb<pid>-<random>.tmp``
  for files, ``.part`` for folders, ``.old`` for a folder being swapped out); the next write into the
  same folder removes those whose process is gone (or that are older than :data:`STALE_AFTER_S`), and
  temporaries of the older naming (``.<name>.<8 random chars>``) of the same target older than
  :data:`LEGACY_STALE_AFTER_S`. Swapped-in folders and files get the umask's permissions.

The verb is found from the call stack (the innermost known workbench module: ``workbench.learn.train``
writes as ``train``, ``workbench.commands.diagnose`` as ``diagnose``), so every caller of
:func:`atomic_dir` gets the guard without passing anything; ``verb=`` overrides it.
"""

from __future__ import annotations

import json
import os
import re
import secrets
import shutil
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

#: the marker file written into every folder atomic_dir swaps in
MARKER = ".workbench-output.json"
#: files a raw folder is recognised by (contract sections 1 and 2)
RAW_MANIFESTS = ("campaign.toml", "trials.toml")
#: a temporary of a live process older than this is swept anyway (the pid was reused)
STALE_AFTER_S = 7 * 24 * 3600.0
#: temporaries of the older naming (no pid) are swept once older than this
LEGACY_STALE_AFTER_S = 3600.0
#: hidden entries of an output folder that are not ours and are carried into its replacement
CARRIED = (".gitignore",)

#: what each verb writes at the top of its output folder: recognises folders written by a workbench
#: older than the marker (e.g. the demo outputs of an existing checkout)
KNOWN_OUTPUTS: dict[str, frozenset[str]] = {
    "diagnose": frozenset({"diagnosis.json", "augmented_model.json", "report.md", "figures",
                           "trajectory_diagnosis.json", "trajectories.png", "trajectory_errors.json",
                           "trajectory_errors.png", "trajectory_diagnosis_reference.json"}),
    "train": frozenset({"config.json", "history.csv", "learning_curve.png", "metrics.json", "model.json",
                        "split.json", "weights.pt"}),
    "tune": frozenset({"best.json", "trials.csv"}),
    "optimize": frozenset({"best.csv", "controller.json", "history.csv", "hypervolume.png", "pareto.png",
                           "population.csv", "trajectories.png"}),
    "score-trials": frozenset({"scores.csv", "summary.json", "comparison.md", "trajectories", "plots", "overlays"}),
    "fit-drag": frozenset({"drag.json", "drag.md", "drag.png"}),
    "simulate": frozenset({"trajectory.parquet", "paths.png", "summary.json"}),
    "sensitivity": frozenset({"sensitivity.json", "sensitivity.png"}),
    "evaluate": frozenset({"prediction_a.png", "prediction_b.png", "prediction_c.png", "prediction_d.png",
                           "mse_boxplot.png"}),
    # a virtual campaign or trials folder: truth.json is what tells it from a real one
    "virtual-lab": frozenset({"campaign.toml", "trials.toml", "runs", "videos", "truth.json"}),
}
#: a legacy folder must hold at least one of these to count as the verb's
_LEGACY_REQUIRED = {"virtual-lab": ("truth.json",)}

#: module (innermost first wins) -> verb; ``workbench.commands.<x>`` maps to ``<x>`` with dashes
_MODULE_VERBS = {
    "workbench.learn.train": "train",
    "workbench.learn.tune": "tune",
    "workbench.trials.outputs": "score-trials",
    "workbench.virtual_lab.tunnel": "virtual-lab",
    "workbench.virtual_lab.towing": "virtual-lab",
    "workbench.virtual_lab.pool": "virtual-lab",
}

_OURS = re.compile(r"^\.(?P<name>.+)\.wb(?P<pid>\d+)-[0-9a-f]{8}\.(?P<kind>tmp|part|old)(?:\..*)?$")


def _output_error(fault: str, path: Path, hint: str | None = None):
    from workbench.errors import ContractError

    return ContractError(fault, path=path, hint=hint)


# -- which verb is writing -------------------------------------------------------------------------------


def current_verb() -> str:
    """The verb writing now, from the call stack (``workbench`` when no verb module is on it)."""
    frame = sys._getframe(1)
    command = None
    while frame is not None:
        mod = frame.f_globals.get("__name__", "")
        if mod in _MODULE_VERBS:
            return _MODULE_VERBS[mod]
        if command is None and mod.startswith("workbench.commands.") and not mod.endswith("._help"):
            command = mod.rsplit(".", 1)[1].replace("_", "-")
        frame = frame.f_back
    return command or "workbench"


# -- raw folders -----------------------------------------------------------------------------------------


def raw_root(path: str | Path) -> Path | None:
    """The raw campaign or trials folder ``path`` is (or lies under), or None.

    A folder being built by :func:`atomic_dir` (a hidden ``.part`` sibling) is not raw yet.
    """
    p = Path(os.path.abspath(path))
    for d in (p, *p.parents):
        if _OURS.match(d.name):
            return None
        if any((d / m).is_file() for m in RAW_MANIFESTS):
            return d
    return None


def check_not_raw(target: str | Path, *, inside_only: bool = False) -> None:
    """Refuse a target inside a raw campaign or trials folder (``inside_only``: the folder itself is allowed)."""
    target = Path(target)
    root = raw_root(target.parent if inside_only else target)
    if root is not None:
        what = "campaign" if (root / "campaign.toml").is_file() else "trials"
        raise _output_error(f"lies inside the raw {what} folder {root}; raw folders are never modified", target,
                            "choose an output outside it")


# -- the marker and the guard ----------------------------------------------------------------------------


def read_marker(folder: str | Path) -> dict | None:
    """The marker of an output folder, or None when it has none (or an unreadable one)."""
    try:
        doc = json.loads((Path(folder) / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def _marker_doc(verb: str) -> dict:
    from workbench import __version__

    # no time stamp: a rerun with the same result leaves DVC's hash of the folder unchanged
    return {"written_by": f"workbench {verb}", "verb": verb, "workbench_version": __version__}


def _is_ours(name: str) -> bool:
    return bool(_OURS.match(name))


def may_replace(folder: str | Path, verb: str) -> tuple[bool, str]:
    """Whether ``verb`` may replace ``folder``, and how it was recognised (or why not)."""
    folder = Path(folder)
    if not folder.exists() and not folder.is_symlink():
        return True, "new"
    if folder.is_symlink() or not folder.is_dir():
        return False, "exists and is not a folder"
    marker = read_marker(folder)
    if marker is not None:
        if marker.get("verb") == verb:
            return True, "marker"
        return False, (f"exists and was written by `workbench {marker.get('verb')}`, not by `workbench {verb}`")
    names = {p.name for p in folder.iterdir()}
    visible = {n for n in names if not n.startswith(".")}
    hidden = {n for n in names - visible if n not in CARRIED and n != MARKER and not _is_ours(n)}
    if not visible and not hidden:
        return True, "empty"
    known = KNOWN_OUTPUTS.get(verb, frozenset())
    required = _LEGACY_REQUIRED.get(verb)
    if (visible and not hidden and visible <= known
            and (required is None or any(r in visible for r in required))):
        return True, "legacy"
    return False, f"exists and was not written by `workbench {verb}`"


def check_replaceable(folder: str | Path, verb: str | None = None) -> str:
    """Raise a one-line error unless ``verb`` may write ``folder`` (see :func:`may_replace`)."""
    folder = Path(folder)
    verb = verb or current_verb()
    ok, how = may_replace(folder, verb)
    if not ok:
        raise _output_error(how, folder, "choose another --out or remove it")
    if any((folder / m).is_file() for m in RAW_MANIFESTS) and how not in ("marker", "legacy"):
        raise _output_error("is a raw folder; raw folders are never modified", folder, "choose another --out")
    check_not_raw(folder, inside_only=True)
    return how


# -- sweeping what killed runs left ----------------------------------------------------------------------


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _remove(p: Path) -> None:
    try:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)
    except OSError:
        pass


def sweep(folder: str | Path, target_name: str | None = None, *, now: float | None = None) -> list[Path]:
    """Remove temporaries of dead writers in ``folder``; return what was removed.

    Ours are recognised by name (``.<name>.wb<pid>-<hex8>.(tmp|part|old)``) and removed when their
    process is gone or they are older than :data:`STALE_AFTER_S`. With ``target_name``, temporaries of
    the older naming for that target (``.<target>.<8 chars>[suffix]``, ``.<target>.old-<pid>``) older
    than :data:`LEGACY_STALE_AFTER_S` go too.
    """
    folder = Path(folder)
    now = time.time() if now is None else now
    removed: list[Path] = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    legacy = None
    if target_name:
        legacy = re.compile(r"^\." + re.escape(target_name) + r"\.(?:[a-z0-9_]{8}(?:\..*)?|old-\d+)$")
    for e in entries:
        if not e.name.startswith("."):
            continue
        m = _OURS.match(e.name)
        if not m and (legacy is None or not legacy.match(e.name)):
            continue
        try:
            age = now - e.stat(follow_symlinks=False).st_mtime
        except OSError:
            continue
        if (m and (not _alive(int(m.group("pid"))) or age > STALE_AFTER_S)) or (not m and age > LEGACY_STALE_AFTER_S):
            _remove(Path(e.path))
            removed.append(Path(e.path))
    return removed


_swept: set[str] = set()


def _sweep_once(folder: Path, target_name: str) -> None:
    """Sweep a folder once per process (a verb writing thousands of files into it scans it once).

    Temporaries of the older naming are recognised for the first target written there.
    """
    key = os.path.abspath(folder)
    if key in _swept:
        return
    _swept.add(key)
    if len(_swept) > 10000:
        _swept.clear()
    sweep(folder, target_name)


# -- files -----------------------------------------------------------------------------------------------


def _tmp_name(target: Path, kind: str, suffix: str = "") -> Path:
    return target.with_name(f".{target.name}.wb{os.getpid()}-{secrets.token_hex(4)}.{kind}{suffix}")


@contextmanager
def atomic_path(target: str | Path, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on success it replaces ``target`` atomically.

    Refused inside a raw campaign or trials folder; stale temporaries beside it are swept first.
    """
    target = Path(target)
    check_not_raw(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    _sweep_once(target.parent, target.name)
    sfx = suffix or ".tmp"
    tmp_path = _tmp_name(target, "tmp", sfx[4:] if sfx.startswith(".tmp") else sfx)
    fd = os.open(tmp_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    os.close(fd)
    try:
        yield tmp_path
        with open(tmp_path, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp_path, 0o666 & ~_umask())  # created 0600; give the usual permissions
        os.replace(tmp_path, target)
        _fsync_dir(target.parent)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_bytes(target: str | Path, data: bytes) -> None:
    """Atomically write bytes."""
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)


def write_text(target: str | Path, text: str) -> None:
    """Atomically write text (UTF-8)."""
    write_bytes(target, text.encode("utf-8"))


def write_json(target: str | Path, obj: Any) -> None:
    """Atomically write pretty JSON with a trailing newline."""
    write_text(target, json.dumps(obj, indent=2, sort_keys=False, default=_json_default) + "\n")


def _json_default(o: Any):
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


# -- folders ---------------------------------------------------------------------------------------------


@contextmanager
def atomic_dir(target: str | Path, verb: str | None = None) -> Iterator[Path]:
    """Build a folder in a hidden sibling and swap it in whole on success (the old one stays on failure).

    ``target`` must be new, empty, or this verb's earlier output (:func:`may_replace`); it must not lie
    inside a raw folder. The new folder gets :data:`MARKER` and the umask's permissions; a DVC-written
    ``.gitignore`` of the old folder is carried over. ``verb`` defaults to :func:`current_verb`.
    """
    target = Path(target)
    verb = verb or current_verb()
    check_replaceable(target, verb)
    target.parent.mkdir(parents=True, exist_ok=True)
    sweep(target.parent, target.name)
    tmp = _tmp_name(target, "part")
    tmp.mkdir(mode=0o700)
    try:
        yield tmp
        check_replaceable(target, verb)  # it may have appeared (or changed hands) while we worked
        for name in CARRIED:
            src = target / name
            if src.is_file() and not (tmp / name).exists():
                shutil.copy2(src, tmp / name)
        marker = tmp / MARKER
        marker.write_text(json.dumps(_marker_doc(verb), indent=2) + "\n", encoding="utf-8")
        os.chmod(marker, 0o666 & ~_umask())
        os.chmod(tmp, 0o777 & ~_umask())
        _fsync_dir(tmp)
        old = None
        if target.exists():
            old = _tmp_name(target, "old")
            os.replace(target, old)
        os.replace(tmp, target)
        _fsync_dir(target.parent)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
