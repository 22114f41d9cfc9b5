"""The campaign registry (``pipelines/campaigns.yaml``) and DVC tracking of raw campaign folders.

``dvc.yaml`` iterates over the registry's lists (``tunnel:``, ``towing:``) with ``foreach``, so a
registered campaign is ingested by the next ``dvc repro``. A real campaign's raw folder is put
under DVC with ``dvc add``; a campaign that a pipeline stage produces (the virtual lab's demo
campaigns) is already a DVC output and is only registered.
"""

from __future__ import annotations

import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from workbench.atomic import write_text
from workbench.contract.campaign import Campaign
from workbench.errors import ContractError, StageError

REGISTRY = Path("pipelines") / "campaigns.yaml"
KEYS = {"water_tunnel": "tunnel", "towing_tank": "towing"}
HEADER = """\
# Campaigns that `dvc repro` ingests: dvc.yaml iterates over these lists with foreach.
# Register one with `workbench campaign add datasets/raw/<id>` (docs/campaigns.md); the command
# rewrites this file, so keep notes in the campaigns' own description fields.
"""


def registry_path(root: Path) -> Path:
    """``<root>/pipelines/campaigns.yaml``."""
    return root / REGISTRY


def load_registry(root: Path) -> dict[str, list[str]]:
    """The registered campaign ids per facility key (``tunnel``, ``towing``)."""
    import yaml

    path = registry_path(root)
    doc = {}
    if path.is_file():
        try:
            doc = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        except yaml.YAMLError as exc:
            raise ContractError(f"not valid YAML: {exc}".splitlines()[0], path=path) from exc
    if not isinstance(doc, dict):
        raise ContractError("expected a mapping of facility -> list of campaign ids", path=path)
    out = {}
    for key in KEYS.values():
        ids = doc.get(key) or []
        if not isinstance(ids, list) or not all(isinstance(i, str) for i in ids):
            raise ContractError(f"'{key}' must be a list of campaign ids", path=path)
        out[key] = list(ids)
    return out


def save_registry(root: Path, registry: dict[str, list[str]]) -> None:
    """Rewrite the registry atomically."""
    lines = [HEADER.rstrip("\n")]
    for key in KEYS.values():
        ids = registry.get(key, [])
        lines.append(f"{key}:" + ("" if ids else " []"))
        lines += [f"  - {i}" for i in ids]
    write_text(registry_path(root), "\n".join(lines) + "\n")


def register(root: Path, campaign: Campaign) -> bool:
    """Add the campaign's id under its facility; False when it was already registered."""
    reg = load_registry(root)
    key = KEYS[campaign.facility]
    if campaign.id in reg[key]:
        return False
    other = [k for k, ids in reg.items() if k != key and campaign.id in ids]
    if other:
        raise ContractError(f"campaign {campaign.id!r} is registered under '{other[0]}' but its facility is "
                            f"{campaign.facility}", path=registry_path(root))
    reg[key].append(campaign.id)
    save_registry(root, reg)
    return True


@dataclass(frozen=True)
class Tracking:
    """How DVC knows a raw folder: ``stage`` output, ``added`` (a .dvc file), or ``untracked``."""

    kind: str
    detail: str = ""


def _stage_out_patterns(root: Path) -> list[tuple[str, str]]:
    """(pattern, stage) for every output named in dvc.yaml (templates become wildcards) and dvc.lock."""
    import yaml

    pats: list[tuple[str, str]] = []
    for name in ("dvc.yaml", "dvc.lock"):
        path = root / name
        if not path.is_file():
            continue
        try:
            doc = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        except yaml.YAMLError:
            continue
        for stage, body in (doc.get("stages") or {}).items():
            if not isinstance(body, dict):
                continue
            for b in (body, body.get("do") if isinstance(body.get("do"), dict) else {}):
                for out in b.get("outs") or []:
                    if isinstance(out, dict):
                        out = out.get("path") or next(iter(out), "")
                    if isinstance(out, str) and out:
                        pats.append((out, stage))
    return pats


def tracking(root: Path, folder: Path) -> Tracking:
    """How DVC tracks ``folder`` (relative to the project ``root``)."""
    rel = folder.resolve().relative_to(root.resolve()).as_posix()
    for pat, stage in _stage_out_patterns(root):
        regex = "^" + re.sub(r"\\\$\\\{[^}]*\\\}", "[^/]+", re.escape(pat.rstrip("/"))) + "(/.*)?$"
        if re.match(regex, rel):
            return Tracking("stage", f"output of stage '{stage}'")
    dvc_file = folder.parent / f"{folder.name}.dvc"
    if dvc_file.is_file():
        if _cut_dvc_file(dvc_file, folder.name):
            return Tracking("untracked", f"{rel}.dvc is empty: a `dvc add` was cut before it wrote it")
        return Tracking("added", f"{rel}.dvc")
    return Tracking("untracked")


def _cut_dvc_file(dvc_file: Path, name: str) -> bool:
    """True when ``dvc_file`` is empty: a `dvc add` was cut before it wrote it.

    DVC opens a .dvc file for writing, then writes it, so a process killed in between leaves it empty,
    and `dvc add` rewrites an empty one. Anything else that does not name the folder is not ours to
    overwrite: a clear error.
    """
    import yaml

    text = dvc_file.read_text(encoding="utf-8", errors="replace")
    if not text.strip():
        return True
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ContractError(f"not valid YAML ({str(exc).splitlines()[0]})", path=dvc_file,
                            hint="a `dvc add` may have been cut while writing it: check it, delete it and "
                                 "run `workbench campaign add` again") from None
    outs = doc.get("outs") if isinstance(doc, dict) else None
    paths = [o.get("path") for o in outs or [] if isinstance(o, dict)]
    if name not in paths:
        raise ContractError(f"does not track the folder {name} (outs: {paths})", path=dvc_file,
                            hint="move that .dvc file aside or run `dvc add` yourself")
    return False


def recover_dvc_rwlock(root: Path) -> Path | None:
    """Set aside DVC's lock record ``.dvc/tmp/rwlock`` when a killed DVC process left it cut.

    DVC rewrites that small JSON file in place (open for writing, then write) under its own guard
    ``rwlock.lock``; a DVC process killed in between leaves it empty, and every later DVC command that
    locks stages then fails with "Unable to read RWLock-file ... JSON structure is corrupted". Under the
    same guard, a file that still does not parse is renamed to ``rwlock.cut-<UTC time>`` beside it (kept,
    not deleted); DVC starts a fresh record. Returns the new name, or None when there was nothing to do.
    """
    import json
    import time

    tmp = root / ".dvc" / "tmp"
    path = tmp / "rwlock"

    def cut() -> bool:
        try:
            json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return False
        except (ValueError, UnicodeDecodeError):
            return True
        return False

    if not cut():
        return None
    from dvc.lock import make_lock

    with make_lock(str(tmp / "rwlock.lock"), tmp_dir=str(tmp), wait=True):
        if not cut():
            return None
        aside = tmp / f"rwlock.cut-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}"
        path.replace(aside)
    from workbench.console import info

    info(f"warning: {path}: DVC's lock record was cut by a killed DVC process; set aside as {aside.name}")
    return aside


def dvc_add(root: Path, folder: Path) -> str:
    """``dvc add`` the folder (run in the project root); returns DVC's output."""
    if not (root / ".dvc").is_dir():
        raise StageError("not a DVC repository", path=root, hint="run `git init && dvc init` in the project first")
    rel = folder.resolve().relative_to(root.resolve()).as_posix()
    recover_dvc_rwlock(root)
    proc = subprocess.run([sys.executable, "-m", "dvc", "add", rel], cwd=root, capture_output=True, text=True)
    if proc.returncode != 0:
        lines = [ln for ln in (proc.stderr + proc.stdout).splitlines() if ln.strip()]
        msg = next((ln for ln in lines if "ERROR" in ln), lines[-1] if lines else "unknown failure")
        raise StageError(f"dvc add failed: {msg.strip()}", path=folder)
    return proc.stdout
