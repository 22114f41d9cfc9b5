"""Issue 8, section 4: the documented walk-through for a new tunnel campaign, run as written.

A copy of the project (dvc.yaml, pipelines/, the workbench sources DVC hashes) in a fresh git + DVC
repository, its knobs shrunk so the whole loop takes minutes:

1. `dvc repro` runs every stage; a second `dvc repro` runs none;
2. the rig's folder goes under datasets/raw/ (the virtual lab writes it, MCAP this time),
   `workbench campaign validate`, `workbench campaign add`, commit the files it names;
3. `dvc repro` runs exactly the stages that depend on the new campaign (its ingest and
   interpolation, train, tune, evaluate and what consumes the retrained model) and nothing else;
   the new campaign is in the training data.
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parents[2]
NEW = "tunnel-2025-03"

pytestmark = pytest.mark.slow

# Every stage the demo dvc.yaml defines for one tunnel and one towing campaign.
ALL_STAGES = {
    "virtual_lab_tunnel", "virtual_lab_towing", "ingest_tunnel@demo-tunnel", "ingest_towing@demo-towing",
    "interpolate@demo-tunnel", "fit_drag@demo-towing", "train", "train_16", "tune", "evaluate",
    "optimize_ef@straight", "optimize_ef@turn", "optimize_lstm@straight", "optimize_lstm@turn",
    "optimize_lstm16@straight", "optimize_lstm16@turn", "optimize_ef_sides", "optimize_lstm_sides",
    "virtual_pool", "score_trials", "virtual_pool_sides", "score_trials_sides", "sensitivity", "diagnose",
    "diagnose_trajectory", "report", "train_ensemble", "plan_campaign",
}
# What a new tunnel campaign must rerun: its own ingest and interpolation, the learned models and
# their evaluation, and what consumes the retrained model (LSTM gaits -> pool -> scores -> report).
DEPENDENT = {
    f"ingest_tunnel@{NEW}", f"interpolate@{NEW}", "train", "train_16", "tune", "evaluate",
    "optimize_lstm@straight", "optimize_lstm@turn", "optimize_lstm16@straight", "optimize_lstm16@turn",
    "optimize_lstm_sides", "virtual_pool", "score_trials", "virtual_pool_sides", "score_trials_sides",
    "diagnose_trajectory", "report", "train_ensemble", "plan_campaign",
}

SMALL_GRID = {"theta_h_min_deg": [10.0, -50.0], "theta_k_max_deg": [-20.0, -60.0],
              "frequency_hz": [0.4, 0.6], "phi_rad": [1.0471975511965976]}


def _set(path: Path, updates: dict) -> None:
    """Merge nested `updates` into a YAML file (the test's copy of a pipelines/*.yaml)."""
    data = yaml.safe_load(path.read_text())

    def merge(dst, src):
        for k, v in src.items():
            if isinstance(v, dict) and isinstance(dst.get(k), dict):
                merge(dst[k], v)
            else:
                dst[k] = v

    merge(data, updates)
    path.write_text(yaml.safe_dump(data, sort_keys=False))


def _shrink(project: Path) -> None:
    """Demo knobs cut down so the loop runs in minutes (what each stage does is unchanged)."""
    p = project / "pipelines"
    _set(p / "virtual_lab.yaml", {"tunnel": {"grid": SMALL_GRID, "cycles": 3},
                                  "towing": {"speeds_mps": [0.08, 0.12, 0.16, 0.2, 0.25, 0.3]}})
    _set(p / "learn.yaml", {
        "train": {"data": {"train_windows_per_epoch": 2000},
                  "trainer": {"max_epochs": 1, "max_time_s": 60, "early_stop_patience": 1}},
        "tune": {"n_trials": 2, "workers": 1, "max_epochs": 1, "train_windows_per_epoch": 1000},
    })
    _set(p / "gait.yaml", {"optimize": {
        "retain": 2, "verify_direct": 2, "nsga2": {"pop_size": 8, "n_gen": 2},
        "tasks": {"straight": {"cap_s": 4.0, "hv_reference": [0.5, 1.0, 5.0]},
                  "turn": {"cap_s": 4.0, "hv_reference": [3.0, 1.6, 5.0]}}}})
    # gait_sides.yaml extends gait.yaml but sets its own search size (test_metrics_plots_and_experiments
    # relies on that): shrunk here like gait.yaml's, still its own
    _set(p / "gait_sides.yaml", {"optimize": {"nsga2": {"pop_size": 8, "n_gen": 2}}})
    # the pool swims the EF's and the FED-LSTM's best gait per task (4 trials; the 16-tick model's gaits are
    # still optimised and still deps of the pool stage): each trial is 60 s of rendered video, scored again
    # in every repro (pool + scoring 78 -> 41 s of CPU per repro, measured 25 Nov 2026)
    _set(p / "trials.yaml", {"pool": {"best": 1, "occlusion_fraction": 0.0, "models": ["ef", "lstm"]},
                             "scoring": {"overlay": False}})
    _set(p / "plan.yaml", {"ensemble": {"members": 2, "train": {"trainer.max_epochs": 1,
                                                                "data.train_windows_per_epoch": 1000}},
                           "plan": {"n_candidates": 24, "swim_s": 4.0, "region_points_per_cycle": 4}})
    _set(p / "diagnose.yaml", {"diagnose": {
        "data": {"max_runs": 16}, "fit": {"search_runs": 8},
        "selection": {"refine": False, "pairs": False, "max_effects": 3}}})


def _env(project: Path) -> dict:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    for k in ("MLFLOW_TRACKING_URI", "WORKBENCH_HOME", "DVC_STAGE"):
        env.pop(k, None)
    env.update({"GIT_AUTHOR_NAME": "walk", "GIT_AUTHOR_EMAIL": "walk@example.org",
                "GIT_COMMITTER_NAME": "walk", "GIT_COMMITTER_EMAIL": "walk@example.org",
                "MPLBACKEND": "Agg", "OPENBLAS_NUM_THREADS": "1", "DVC_NO_ANALYTICS": "1"})
    return env


def _run(args: list[str], project: Path, timeout: float = 900, stdout_only: bool = False) -> str:
    proc = subprocess.run(args, cwd=project, env=_env(project), capture_output=True, text=True,
                          timeout=timeout)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, f"{' '.join(args)} failed ({proc.returncode}):\n{out[-6000:]}"
    return proc.stdout if stdout_only else out


def _ran(output: str) -> set[str]:
    """Stages `dvc repro` ran (it prints "Running stage 'x':" for each)."""
    return set(re.findall(r"Running stage '([^']+)'", output))


def _digest(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def project(tmp_path_factory) -> Path:
    proj = tmp_path_factory.mktemp("walkthrough") / "lab"
    proj.mkdir()
    for name in ("dvc.yaml", ".gitignore", ".dvcignore"):
        shutil.copy2(REPO / name, proj / name)
    shutil.copytree(REPO / "pipelines", proj / "pipelines")
    shutil.copytree(REPO / "workbench", proj / "workbench",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    _shrink(proj)
    _run(["git", "init", "-q"], proj)
    _run(["dvc", "init", "-q"], proj)
    _run(["dvc", "config", "core.autostage", "true"], proj)
    _run(["git", "add", "-A"], proj)
    _run(["git", "commit", "-qm", "lab"], proj)
    return proj


def test_new_tunnel_campaign_reruns_only_what_depends_on_it(project):
    # 1. The whole loop, then nothing to do.
    first = _run(["dvc", "repro"], project, timeout=1800)
    assert _ran(first) == ALL_STAGES, first[-4000:]
    again = _run(["dvc", "repro"], project)
    assert _ran(again) == set(), again[-3000:]
    _run(["git", "add", "-A"], project)
    _run(["git", "commit", "-qm", "demo results"], project)

    untouched = {
        "processed demo tunnel": project / "datasets/processed/demo-tunnel.parquet",
        "drag fit": project / "datasets/drag/demo-towing/drag.json",
        "EF straight gaits": project / "datasets/gaits/straight-ef.json",
        "diagnosis": project / "datasets/diagnosis/demo-tunnel-ef/diagnosis.json",
    }
    before = {k: _digest(p) for k, p in untouched.items()}
    metrics_before = _digest(project / "datasets/metrics/leg_models.json")

    # 2. Step 1 of the walk-through: the rig's files go under datasets/raw/ (MCAP, another seed).
    raw = project / "datasets" / "raw" / NEW
    _run(["workbench", "virtual-lab", "tunnel", str(raw.relative_to(project)), "--params",
          "pipelines/virtual_lab.yaml", "--seed", "11", "--form", "mcap"], project)
    raw_digest = {p.relative_to(raw): _digest(p) for p in raw.rglob("*") if p.is_file()}

    # Steps 3-4: validate, add, commit the files `add` names.
    out = _run(["workbench", "campaign", "validate", f"datasets/raw/{NEW}"], project)
    assert "valid" in out
    out = _run(["workbench", "campaign", "add", f"datasets/raw/{NEW}"], project)
    assert f"registered {NEW} in pipelines/campaigns.yaml" in out
    assert (project / "datasets" / "raw" / f"{NEW}.dvc").is_file()
    names = re.search(r"commit it: git add (.+)", out)
    assert names, out
    _run(["git", "add", *names.group(1).split()], project)
    _run(["git", "commit", "-qm", f"campaign {NEW}"], project)
    registry = yaml.safe_load((project / "pipelines" / "campaigns.yaml").read_text())
    assert registry["tunnel"] == ["demo-tunnel", NEW]

    # Step 5: dvc repro reprocesses, retrains and re-evaluates only what depends on the campaign.
    status = _run(["dvc", "status"], project)
    assert "ingest_tunnel@demo-tunnel" not in status and "fit_drag@demo-towing" not in status
    second = _run(["dvc", "repro"], project, timeout=1800)
    ran = _ran(second)
    assert ran == DEPENDENT, (f"ran {sorted(ran)}; expected {sorted(DEPENDENT)}\n" + second[-3000:])
    for key, path in untouched.items():
        assert _digest(path) == before[key], f"{key} changed although it does not depend on {NEW}"
    assert _digest(project / "datasets/metrics/leg_models.json") != metrics_before

    # The new campaign was processed and trained on; the raw folder is untouched.
    assert (project / f"datasets/processed/{NEW}.parquet").is_file()
    assert (project / f"datasets/processed/interp/{NEW}.parquet").is_file()
    split = json.loads((project / "datasets/models/fed-lstm/split.json").read_text())
    assert NEW in json.dumps(split), "the retrained model's split does not mention the new campaign"
    assert {p.relative_to(raw): _digest(p) for p in raw.rglob("*") if p.is_file()} == raw_digest

    # Step 6: `campaign list` shows it registered, tracked and processed; nothing is left to run.
    listing = _run(["workbench", "campaign", "list"], project)
    line = next(ln for ln in listing.splitlines() if NEW in ln)
    assert "processed" in line.lower() or "yes" in line.lower(), listing
    assert _ran(_run(["dvc", "repro"], project)) == set()


def test_metrics_plots_and_experiments(project):
    """`dvc metrics show`, `dvc plots show` (PNG plots too) and `dvc exp run -S` on the same loop."""
    _run(["dvc", "repro"], project, timeout=1800)  # nothing to do after the walk-through

    metrics = json.loads(_run(["dvc", "metrics", "show", "--json"], project, stdout_only=True))
    files = {name for ws in metrics.values() for name in ws.get("data", {})}
    # people-sized: the loop's results in one small file, not every stage's timings and paths
    assert files == {"datasets/reports/headline.json"}, sorted(files)
    head = json.loads((project / "datasets/reports/headline.json").read_text())
    assert {"lstm_over_ef_mse", "best_S", "pool_time_s", "diagnosis"} <= set(head)

    _run(["dvc", "plots", "show", "-o", "plots-out"], project)
    html = (project / "plots-out" / "index.html").read_text()
    static = {p.name for p in (project / "plots-out").rglob("*.png")}
    assert "drag.png" in " ".join(static) and "boxplots.png" in " ".join(static), sorted(static)
    assert html.count("<img") >= 3
    # learning curves and hypervolume histories are data plots (CSV), so `dvc plots diff` overlays runs
    assert "learning_curve" in html and "hypervolume" in html

    # An experiment with one knob changed: only the gait stages and what follows them run again.
    out = _run(["dvc", "exp", "run", "-n", "more-generations", "-S", "pipelines/gait.yaml:optimize.nsga2.n_gen=3"],
               project, timeout=1800)
    assert _ran(out) == {"optimize_ef@straight", "optimize_ef@turn", "optimize_lstm@straight",
                         "optimize_lstm@turn", "optimize_lstm16@straight", "optimize_lstm16@turn",
                         # gait_sides.yaml extends gait.yaml, so its stages run again, but it sets its own
                         # nsga2 size: their gait files come out the same and the sides pool is not swum again
                         "optimize_ef_sides", "optimize_lstm_sides",
                         "virtual_pool", "score_trials",
                         "sensitivity", "diagnose_trajectory", "report", "plan_campaign"}, out[-3000:]
    table = _run(["dvc", "exp", "show", "--csv"], project, stdout_only=True)
    header, *rows = list(csv.reader(io.StringIO(table.strip())))  # quoted values hold commas (lists)
    # two params files hold optimize.nsga2.n_gen (gait_sides.yaml extends gait.yaml): DVC prefixes the file then
    col = next(i for i, h in enumerate(header) if _is_n_gen(h))
    assert any(r[0] == "more-generations" and r[col] == "3" for r in rows), table
    # what docs/pipeline.md shows fits a terminal: metrics diff (one row per changed number) and
    # exp show with the documented flags
    diff = _run(["dvc", "metrics", "diff", "HEAD", "more-generations"], project, stdout_only=True)
    assert "best_S" in diff and max(len(line) for line in diff.splitlines()) <= 120, diff
    # as documented (README, docs/pipeline.md): changed dependency hashes (datasets/, workbench/) dropped
    shown = _run(["dvc", "exp", "show", "--only-changed", "--drop", "^(datasets|workbench)/", "--csv"], project,
                 stdout_only=True)
    header = next(csv.reader(io.StringIO(shown)))
    # people-sized: the knob that changed and the results it moved, not 1,260 columns
    # (49 columns since the per_side_range turn added its pool results to headline.json)
    assert any(_is_n_gen(h) for h in header) and "best_S.turn-lstm" in header and len(header) <= 60, header
    assert not any(h.startswith(("datasets/", "workbench/")) for h in header), header


def _is_n_gen(column: str) -> bool:
    """gait.yaml's optimize.nsga2.n_gen in `dvc exp show`, bare or prefixed with its file."""
    return column == "optimize.nsga2.n_gen" or column.endswith("gait.yaml:optimize.nsga2.n_gen")


def _tour_commands() -> list[str]:
    """The README's tour, as written: the indented command lines of its "A short tour" section."""
    text = (REPO / "README.md").read_text()
    section = text.split("## A short tour", 1)[1].split("\n## ", 1)[0]
    cmds = []
    for line in section.splitlines():
        if line.startswith("    ") and line.strip().split(" ", 1)[0] in ("workbench", "dvc"):
            cmds.append(line.strip().split("  #", 1)[0].strip())
    return cmds


def _champion(project: Path) -> str | None:
    from mlflow import MlflowClient
    from mlflow.exceptions import MlflowException

    client = MlflowClient(tracking_uri=f"sqlite:///{project / 'mlflow.db'}")
    try:
        return client.get_model_version_by_alias("fed-lstm", "champion").version
    except MlflowException:
        return None


def test_readme_tour_runs_as_written_and_touches_nothing(project):
    """Issue 15.2: every tour command runs as written on the demo outputs; afterwards `dvc status` is
    clean and the champion alias has not moved (ad-hoc results go to scratch/)."""
    import shlex

    _run(["dvc", "repro"], project, timeout=1800)
    status_before = _run(["dvc", "status"], project, stdout_only=True)
    assert "up to date" in status_before, status_before
    champion = _champion(project)
    assert champion is not None
    cmds = _tour_commands()
    assert len(cmds) >= 12 and any(c.startswith("workbench train") for c in cmds), cmds
    ran = []
    for cmd in cmds:
        if cmd.startswith("workbench ui"):
            continue  # long-running: its start and stop are tested in tests/faults/test_processes.py
        if cmd.startswith(("dvc repro", "dvc exp run")):
            continue  # run by the tests above
        _run(shlex.split(cmd), project, timeout=1200)
        ran.append(cmd)
    assert _run(["dvc", "status"], project, stdout_only=True) == status_before
    assert _champion(project) == champion
    assert (project / "scratch" / "quick-model" / "weights.pt").is_file()
    assert (project / "scratch" / "what-changed" / "diagnosis.json").is_file()
    assert len(ran) >= 12
