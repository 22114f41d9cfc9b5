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
    if (folder.parent / f"{folder.name}.dvc").is_file():
        return Tracking("added", f"{rel}.dvc")
    return Tracking("untracked")


def dvc_add(root: Path, folder: Path) -> str:
    """``dvc add`` the folder (run in the project root); returns DVC's output."""
    if not (root / ".dvc").is_dir():
        raise StageError("not a DVC repository", path=root, hint="run `git init && dvc init` in the project first")
    rel = folder.resolve().relative_to(root.resolve()).as_posix()
    proc = subprocess.run([sys.executable, "-m", "dvc", "add", rel], cwd=root, capture_output=True, text=True)
    if proc.returncode != 0:
        lines = [ln for ln in (proc.stderr + proc.stdout).splitlines() if ln.strip()]
        msg = next((ln for ln in lines if "ERROR" in ln), lines[-1] if lines else "unknown failure")
        raise StageError(f"dvc add failed: {msg.strip()}", path=folder)
    return proc.stdout
