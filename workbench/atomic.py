"""Atomic output that never loses anything: files and folders are built beside their target and swapped in.

Three rules hold for every verb that writes through this module (docs/data-outputs.md):

* **Whole or old.** A file is written to a temporary sibling, fsynced and renamed over its target; a
  folder is built in a hidden sibling and swapped in whole (one atomic exchange of the two names where
  the file system can). A kill at any moment leaves either the previous output or the new one, never a
  mix. Several files in a folder others share (:func:`atomic_files`: ``report``, ``optimize``) are
  committed by a journal and renamed after it; a kill after the commit is completed by the next write.
* **Never delete what we did not write.** :func:`atomic_dir` replaces an existing folder only when it
  holds this verb's earlier output: a marker file (:data:`MARKER`, written into every folder it swaps
  in) naming the verb, or, for folders written before markers existed, content made only of names the
  verb is known to write (:data:`KNOWN_OUTPUTS`). Anything else is refused with a one-line error.
  Nothing is ever written inside a raw campaign or trials folder (one holding ``campaign.toml`` or
  ``trials.toml``, or anything under one).
* **Nothing left behind.** Temporary names carry the writer's pid (``.<name>.wb<pid>-<random>.tmp``
  for files, ``.part`` for folders, ``.old`` for a folder being swapped out, ``.set`` for a file set's
  journal); the next write into the same folder first completes what a dead writer committed or left
  half swapped, then removes those whose process is gone (or older than :data:`STALE_AFTER_S`), and
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
    "evaluate": frozenset({*(f"prediction_{c}.png" for c in "abcdefgh"), "mse_boxplot.png"}),
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

_OURS = re.compile(r"^\.(?P<name>.+)\.wb(?P<pid>\d+)-[0-9a-f]{8}\.(?P<kind>tmp|part|old|set)(?:\..*)?$")


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
    than :data:`LEGACY_STALE_AFTER_S` go too. Before anything is removed, what a killed writer left half
    swapped is completed (:func:`_recover`): a file set whose journal was written is rolled forward, and a
    folder swapped out (``.old``) whose replacement never arrived is put back.
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
    entries = _recover(folder, entries)
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


def _dead(m: re.Match) -> bool:
    return not _alive(int(m.group("pid")))


def _recover(folder: Path, entries: list) -> list:
    """Complete what dead writers left half swapped in ``folder``; return the folder's entries after it.

    * a file-set journal (``.<verb>.wb<pid>-<hex>.set``, :func:`atomic_files`): the set was committed,
      so its remaining temporaries are renamed over their targets and the journal removed;
    * a folder swapped out (``.<name>.wb<pid>-<hex>.old``) while ``<name>`` is missing: the kill came
      between the two renames of :func:`atomic_dir`'s fallback swap; the old folder is put back.
    """
    def rescan() -> list:
        _fsync_dir(folder)
        try:
            return list(os.scandir(folder))
        except OSError:
            return []

    journals = [e for e in entries if (m := _OURS.match(e.name)) and m.group("kind") == "set" and _dead(m)]
    for e in journals:  # first: a committed set moves its folders aside and in
        _roll_forward(folder, Path(e.path))
    if journals:
        entries = rescan()
    restored = False
    for e in entries:
        m = _OURS.match(e.name)
        if m and m.group("kind") == "old" and _dead(m) and not os.path.lexists(folder / m.group("name")):
            try:
                os.replace(e.path, folder / m.group("name"))
                restored = True
            except OSError:
                pass
    return rescan() if restored else entries


def _roll_forward(folder: Path, journal: Path) -> None:
    """Complete a committed set: rename what is left of it into place (each step can be repeated)."""
    try:
        doc = json.loads(journal.read_text(encoding="utf-8"))
        moves, dirs = dict(doc["files"]), dict(doc.get("dirs", {}))
    except (OSError, ValueError, KeyError, TypeError):
        journal.unlink(missing_ok=True)  # never whole (it is renamed into place): nothing was committed
        return
    olds = []  # removed only once every name holds the new set: the mixed moment is the renames alone
    for name, part in dirs.items():  # a folder: the old one moves aside, the new one in (part: always the new)
        src, dst = folder / part, folder / name
        if "/" in name or "/" in part or not src.is_dir():
            continue
        if os.path.lexists(dst):
            olds.append(_tmp_name(dst, "old"))
            os.replace(dst, olds[-1])
        os.replace(src, dst)
    for name, tmp in moves.items():
        src = folder / tmp
        if os.path.lexists(src) and "/" not in name and "/" not in tmp:
            os.replace(src, folder / name)
    for old in olds:
        shutil.rmtree(old, ignore_errors=True)
    if doc.get("record"):
        name, text = doc["record"]
        tmp = _tmp_name(folder / name, "tmp")
        tmp.write_text(text, encoding="utf-8")
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, folder / name)
    _fsync_dir(folder)
    journal.unlink(missing_ok=True)
    _fsync_dir(folder)


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


def json_text(obj: Any) -> str:
    """Pretty JSON with a trailing newline, as :func:`write_json` writes it (numpy values and paths allowed)."""
    return json.dumps(obj, indent=2, sort_keys=False, default=_json_default) + "\n"


def write_json(target: str | Path, obj: Any) -> None:
    """Atomically write pretty JSON with a trailing newline."""
    write_text(target, json_text(obj))


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
def atomic_dir(target: str | Path, verb: str | None = None, *, marker: bool = True) -> Iterator[Path]:
    """Build a folder in a hidden sibling and swap it in whole on success (the old one stays on failure).

    ``target`` must be new, empty, or this verb's earlier output (:func:`may_replace`); it must not lie
    inside a raw folder. The new folder gets :data:`MARKER` and the umask's permissions; a DVC-written
    ``.gitignore`` of the old folder is carried over. ``verb`` defaults to :func:`current_verb`.
    ``marker=False``: no marker (a folder DVC shows as plots, where every file is drawn); the folder is
    then recognised as the verb's by its names (:data:`KNOWN_OUTPUTS`), which must all be known ones.
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
        if marker:
            marker_file = tmp / MARKER
            marker_file.write_text(json.dumps(_marker_doc(verb), indent=2) + "\n", encoding="utf-8")
            os.chmod(marker_file, 0o666 & ~_umask())
        os.chmod(tmp, 0o777 & ~_umask())
        _fsync_dir(tmp)
        old = None
        if target.exists() and not _exchange(tmp, target):  # one atomic swap: tmp now holds the old folder
            old = _tmp_name(target, "old")  # no exchange here: two renames; a kill between them is put right
            os.replace(target, old)         # by the next sweep of this folder (the old folder goes back)
        if old is not None or not target.exists():
            os.replace(tmp, target)
        _fsync_dir(target.parent)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one atomic step (Linux ``renameat2(RENAME_EXCHANGE)``); False where unsupported."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes
    import errno

    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):  # a libc without it (glibc < 2.28, musl)
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):  # the file system cannot
        return False
    raise OSError(err, os.strerror(err), str(b))


# -- sets of files in a shared folder --------------------------------------------------------------------


def set_record_name(set_name: str) -> str:
    """The hidden record naming the files of one set (a verb's, or ``<verb>-<what>``) in a shared folder."""
    return f".workbench-set-{set_name}.json"


def read_set_record(folder: str | Path, set_name: str) -> dict | None:
    """The record of set ``set_name`` in ``folder`` (its ``files`` are that set's), or None."""
    try:
        doc = json.loads((Path(folder) / set_record_name(set_name)).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and isinstance(doc.get("files"), list) else None


def _check_files_replaceable(folder: Path, names: list[str], dirs: list[str], verb: str, set_name: str,
                             recognise) -> None:
    marker = read_marker(folder)
    if marker is not None and marker.get("verb") != verb:
        raise _output_error(f"is the output folder of `workbench {marker.get('verb')}`; `workbench {verb}` "
                            "does not write into it", folder, "choose another --out")
    listed = set((read_set_record(folder, set_name) or {}).get("files", []))
    for name in names:
        p = folder / name
        if not os.path.lexists(p) or name in listed:
            continue
        if p.is_symlink() or not p.is_file() or recognise is None or not recognise(p):
            raise _output_error(f"exists and was not written by `workbench {verb}`", p,
                                "choose another --out or remove it")
    for name in dirs:
        check_replaceable(folder / name, verb)


@contextmanager
def atomic_files(folder: str | Path, names: list[str] | tuple[str, ...], verb: str | None = None, *,
                 dirs: list[str] | tuple[str, ...] = (), set_name: str | None = None,
                 recognise=None) -> Iterator[dict[str, Path]]:
    """Write several files (and folders) into a folder other outputs share, as one set: all new or all old.

    Yields ``{name: temporary path}`` for each file of ``names`` (an empty file) and each folder of
    ``dirs`` (an empty folder, given :data:`MARKER` like :func:`atomic_dir`); write them. On success
    the set is committed by a journal (``.<set>.wb<pid>-<hex>.set``, renamed into place whole), then
    each is renamed over its target. A kill before the journal leaves the old set (the temporaries
    are swept); a kill after it is rolled forward by the next write into the folder (:func:`sweep`):
    the new set, whole. The set's record (:func:`set_record_name`, ``set_name`` defaults to the
    verb) lists its files, so the next run may replace them; a file of one of those names that the
    record does not list is replaced only when ``recognise(path)`` says it is this verb's (written
    before records existed), otherwise refused with a one-line error; folders as :func:`atomic_dir`.
    """
    folder = Path(folder)
    verb = verb or current_verb()
    set_name = set_name or verb
    names, dirs = list(names), list(dirs)
    check_not_raw(folder / (names + dirs)[0])
    folder.mkdir(parents=True, exist_ok=True)
    sweep(folder)  # completes a set a killed run committed, removes dead temporaries
    _check_files_replaceable(folder, names, dirs, verb, set_name, recognise)
    tmps = {n: _tmp_name(folder / n, "tmp") for n in names}
    parts = {n: _tmp_name(folder / n, "part") for n in dirs}
    journal_tmp = _tmp_name(folder / set_name, "tmp")
    try:
        for t in tmps.values():
            os.close(os.open(t, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        for t in parts.values():
            t.mkdir(mode=0o700)
        yield {**tmps, **parts}
        for name, t in parts.items():
            check_replaceable(folder / name, verb)  # it may have appeared (or changed hands) while we worked
            (t / MARKER).write_text(json.dumps(_marker_doc(verb), indent=2) + "\n", encoding="utf-8")
            for p in (t / MARKER, t):
                os.chmod(p, (0o777 if p.is_dir() else 0o666) & ~_umask())
            _fsync_dir(t)
        for t in tmps.values():
            with open(t, "rb+") as fh:
                os.fsync(fh.fileno())
            os.chmod(t, 0o666 & ~_umask())
        record = json.dumps({**_marker_doc(verb), "files": sorted(names + dirs)}, indent=2) + "\n"
        journal_tmp.write_text(json.dumps({"files": {n: t.name for n, t in tmps.items()},
                                           "dirs": {n: t.name for n, t in parts.items()},
                                           "record": [set_record_name(set_name), record]}), encoding="utf-8")
        with open(journal_tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        journal = _tmp_name(folder / set_name, "set")
        os.replace(journal_tmp, journal)  # the commit: from here the new set wins, even after a kill
        _fsync_dir(folder)
        _roll_forward(folder, journal)
    finally:
        for t in (*tmps.values(), journal_tmp):
            if t.exists():
                t.unlink()
        for t in parts.values():
            if t.exists():
                shutil.rmtree(t, ignore_errors=True)
