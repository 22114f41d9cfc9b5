"""The files ``workbench diagnose --trials`` reads: scored trials, the tank's size, the trials' gait files.

:mod:`workbench.diagnose.trajectory` takes data; this is where the files are opened: the
``score-trials`` output folder (``scores.csv``, ``trajectories/<trial_id>.parquet``,
``summary.json`` naming the trials folder), that folder's ``trials.toml`` (the tank) and the gait
files ``<task>-<model>.json``.
"""

from __future__ import annotations

from pathlib import Path


def tank_size(scores_dir: str | Path) -> tuple[float, float] | None:
    """(width, length) of the tank from the scored trials folder's ``trials.toml`` (None when unknown)."""
    import tomllib

    from workbench.contract.jsonfile import read_json
    from workbench.errors import ContractError
    from workbench.project import project_root

    root = Path(scores_dir)
    try:
        trials_dir = read_json(root / "summary.json").get("trials_dir")
    except (ContractError, OSError, AttributeError):
        return None
    if not trials_dir:
        return None
    for base in (Path(trials_dir), project_root() / trials_dir, root.parent / trials_dir):
        toml = base / "trials.toml"
        if toml.is_file():
            try:
                tank = tomllib.loads(toml.read_text(encoding="utf-8")).get("tank") or {}
                return float(tank["width_m"]), float(tank["length_m"])
            except (OSError, ValueError, KeyError, TypeError):
                return None
    return None


def read_tracks(scores_dir: str | Path, tank_m: tuple[float, float] | None = None,
                wall_margin_m: float = 0.25) -> list:
    """The scored trials of a ``score-trials`` output folder (scores.csv + trajectories/*.parquet) as tracks.

    ``tank_m`` (width, length; default: from the trials folder named in summary.json): each track
    is cut where the robot comes within ``wall_margin_m`` of a wall
    (:func:`workbench.diagnose.trajectory.track_from_frame`).
    """
    import polars as pl

    from workbench.diagnose.trajectory import track_from_frame
    from workbench.errors import ContractError, DataError

    root = Path(scores_dir)
    csv = root / "scores.csv"
    if not csv.is_file():
        raise ContractError("no scores.csv here", path=root, hint="run `workbench score-trials DIR --out DIR` first")
    if tank_m is None:
        tank_m = tank_size(root)
    out = []
    for row in pl.read_csv(csv).iter_rows(named=True):
        path = root / "trajectories" / f"{row['trial_id']}.parquet"
        if not path.is_file():
            raise DataError("trajectory file missing", path=path)
        out.append(track_from_frame(row, pl.read_parquet(path), tank_m, wall_margin_m, where=path))
    return out


def read_track_gaits(gaits_dir: str | Path, tracks: list) -> list[tuple[dict, dict]]:
    """Per track, the ``(params, fixed)`` of the gait it swam, from ``<gaits_dir>/<task>-<model>.json``."""
    from workbench.contract.jsonfile import read_json
    from workbench.diagnose.trajectory import gait_file_name, gait_from_doc

    docs: dict[Path, object] = {}
    out = []
    for tr in tracks:
        path = Path(gaits_dir) / gait_file_name(tr)
        if path not in docs:
            docs[path] = read_json(path, "gait file", hint="the gaits folder of `workbench optimize` (--gaits DIR)")
        out.append(gait_from_doc(docs[path], tr, where=path))
    return out


def tabulator(model, batch, dt_s: float):
    """A window net swum through the optimiser's per-gait cycle tables (``simulate_tracks``' ``tabulate``)."""
    from workbench.gait.tabulate import TabulatedLegModel

    return TabulatedLegModel(model, batch, sim_dt_s=dt_s)
