"""Light plugin: lets :func:`workbench.hydro.legmodel.load_leg_model` load augmented models.

``load_leg_model("augmented:datasets/diagnosis/demo-tunnel-ef")`` (a folder or its
``augmented_model.json``) returns the load-cell reading model;
``"augmented-physical:<path>"`` the physical leg only (for the simulator and the optimiser).
No heavy imports here. The three loaders below are entries of the ``workbench.leg_models``
entry-point group in ``pyproject.toml`` (read by :mod:`workbench.hydro.legmodel`).
"""


def load(spec: str, **kwargs):
    """``augmented:<path>`` -> the augmented model (load-cell reading)."""
    from workbench.diagnose.augmented import load_augmented

    return load_augmented(spec.split(":", 1)[1], **kwargs)


def load_physical(spec: str, **kwargs):
    """``augmented-physical:<path>`` -> the physical part of the augmented model."""
    return load("augmented:" + spec.split(":", 1)[1], **kwargs).physical()


def load_path(path: str, **kwargs):
    """A path to a saved augmented model (its JSON, or a folder holding ``augmented_model.json``); else None."""
    import json
    from pathlib import Path

    p = Path(path)
    if p.is_dir():
        p = p / "augmented_model.json"
    if not p.is_file() or p.suffix != ".json":
        return None
    try:
        head = json.loads(p.read_text(encoding="utf-8")).get("schema")
    except (OSError, ValueError, AttributeError):
        return None
    if head != "workbench/augmented-leg-model@1":
        return None
    from workbench.diagnose.augmented import load_augmented

    return load_augmented(p, **kwargs)

