"""kill -9 at random moments of the other writing verbs: every output stays one complete set.

The style of test_kills.py: each verb writes a first complete output (set A) and then a second one
(set B, timed); then the real CLI is started again in its own process group, aiming each time at
the set not there now, and the group is SIGKILLed at random moments (seeded: FAULT_SEED, FAULT_KILLS
of them): one in start-up, the rest over the later 60 % of a run, where the writing happens; and one
more the moment the command's first temporary shows up (inside the writing whatever the load). After
every kill the output must be set A or set B, whole (every file readable, the files of one run
together; for the deterministic verbs the same content as the set the verb wrote), no temporary may
be visible as an output, and after the next complete run no temporary may be left at all.

``campaign add`` (registry, then ``dvc add``) is killed while adding a new campaign: the registry
whole, the raw folder unchanged, and the next add completes the registration and the tracking.
``acquire`` writes raw data as it arrives: after a kill the capture is a prefix of what the device
sent, decodable by the contract's reader, and never overwritten by a later recording.

Inputs are tiny and built here (no demo outputs needed). The kills that landed inside a run are
printed per verb and, with FAULT_COUNTS=<file>, appended to that file as JSON lines.
"""

from __future__ import annotations

import hashlib
import json
import os
import random
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from faults_helpers import ROOT, kill_after, leftovers
from proctree import project_env, small_parquet, tiny_learn_config

from workbench.atomic import MARKER, may_replace, read_marker, sweep

pytestmark = [pytest.mark.faults, pytest.mark.slow]

SEED = int(os.environ.get("FAULT_SEED", "16"))
KILLS = int(os.environ.get("FAULT_KILLS", "3"))
PIPE = ROOT / "pipelines"


# -- running and killing ---------------------------------------------------------------------------------


def _run(env: dict, cwd: Path, *args: str) -> float:
    """Run ``workbench ARGS`` to the end (must succeed); return its wall time."""
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "workbench.cli", *args], cwd=cwd, env=env, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, f"workbench {' '.join(args)}:\n{r.stderr[-3000:]}"
    return time.perf_counter() - t0


def _env(tmp: Path) -> dict:
    """An isolated project in ``tmp`` (its own MLflow store, Optuna folder, temp folder) with the real pipelines/."""
    if not (tmp / "pipelines").exists():
        (tmp / "pipelines").symlink_to(PIPE)
    return project_env(tmp)


def _kill_when_writing(env: dict, cwd: Path, watch: list[Path], *args: str) -> bool:
    """Start ``workbench ARGS``; SIGKILL its group the moment one of its temporaries shows up in ``watch``.

    Returns whether it was killed while writing (False: it ended first).
    """
    proc = subprocess.Popen([sys.executable, "-m", "workbench.cli", *args], cwd=cwd, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    mine = f".wb{proc.pid}-"
    try:
        while proc.poll() is None:
            if any(mine in p for folder in watch for p in leftovers(folder)):
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                return True
            time.sleep(0.005)
        return False
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _state_after_kill(state, watch: list[Path]) -> str:
    """``state()`` after a kill; a mixed set is allowed only inside a committed set's renames.

    A set of files in a shared folder (``atomic_files``) is committed by a journal and then renamed
    file by file; a kill inside those renames (microseconds) leaves the journal of a dead writer, and
    the next write into the folder completes it (docs/data-outputs.md). Then, and only then, the
    folder may hold two runs' files: the sweep any next write does must make it the new set, whole.
    """
    try:
        return state()
    except Exception:  # noqa: BLE001 - whatever the mixed set broke; re-raised unless a journal explains it
        journals = [p for folder in watch for p in leftovers(folder) if p.endswith(".set")]
        if not journals:
            raise
    for folder in watch:
        sweep(folder)
    assert not [p for folder in watch for p in leftovers(folder) if p.endswith(".set")]
    return state()


def _visible_temporaries(folder: Path) -> list[str]:
    """Anything under ``folder``, outside hidden entries, named like a temporary or a partial write."""
    if not folder.is_dir():
        return []
    return sorted(str(p) for p in folder.rglob("*")
                  if not any(part.startswith(".") for part in p.relative_to(folder).parts)
                  and re.search(r"(\.(tmp|part|partial|old|crdownload)|~)$|\.wb\d+-", p.name))


def _moments(name: str, full_s: float, n: int) -> list[float]:
    """One kill in start-up, the rest over the later part of a run (the writing is at its end)."""
    rng = random.Random(f"{SEED}-{name}")
    return [0.3 + rng.random() * 0.5] + [rng.uniform(0.4 * full_s, 1.0 * full_s) for _ in range(n - 1)]


def _count(name: str, survived: int, kills: int, writing: int | None = None) -> None:
    line = {"verb": name, "kills": kills, "landed_inside_a_run": survived, "left_a_temporary": writing}
    during = "" if writing is None else f" ({writing} while writing: they left a temporary)"
    print(f"{name}: {survived} of {kills} kills landed inside a run{during}; every output whole after each")
    path = os.environ.get("FAULT_COUNTS")
    if path:
        with open(path, "a", encoding="utf-8") as fh:
            fh.write(json.dumps(line) + "\n")


def kill_cycle(name: str, tmp: Path, runs: dict[str, tuple[str, ...]], state, watch: list[Path],
               env: dict | None = None, kills: int = KILLS) -> None:
    """Set A, set B (timed), then ``kills`` kills each aimed at the other set; ``state()`` names the set there.

    ``state`` asserts the output is whole and one set and returns its label ("a" or "b").
    ``watch``: the folders where no temporary may be visible after a kill or left after the last run.
    """
    env = env or _env(tmp)
    _run(env, tmp, *runs["a"])
    assert state() == "a"
    full = _run(env, tmp, *runs["b"])
    assert state() == "b"
    survived = writing = 0
    for delay in _moments(name, full, kills):
        other = "b" if state() == "a" else "a"
        rc = kill_after(delay, *runs[other], env=env, cwd=tmp)
        got = _state_after_kill(state, watch)
        if rc is not None:
            assert rc == 0 and got == other, f"{name}: ended with {rc} before the kill, set {got!r}"
        left = [p for folder in watch for p in leftovers(folder)]
        visible = [p for folder in watch for p in _visible_temporaries(folder)]
        assert visible == [], f"{name}: temporaries visible as outputs: {visible}"
        writing += bool(left)
        survived += rc is None
    # and once at the first sight of its temporaries: inside the writing, whatever the machine's load
    other = "b" if state() == "a" else "a"
    caught = _kill_when_writing(env, tmp, watch, *runs[other])
    assert _state_after_kill(state, watch) in ("a", "b") and (caught or state() == other)
    _run(env, tmp, *runs["a"])
    assert state() == "a"
    for folder in watch:
        assert leftovers(folder) == [], f"{name}: temporaries of killed runs were not swept: {leftovers(folder)}"
    _count(name, survived + caught, kills + 1, writing + caught)
    assert survived >= 1, f"{name}: no kill landed inside a run"


# -- what a set looks like -------------------------------------------------------------------------------


def _rounded(obj):
    if isinstance(obj, float):
        return float(f"{obj:.9g}")
    if isinstance(obj, dict):
        return {k: _rounded(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_rounded(v) for v in obj]
    return obj


def _drop_columns(data: bytes, columns: tuple[str, ...]) -> bytes:
    rows = [line.split(",") for line in data.decode().splitlines()]
    keep = [i for i, c in enumerate(rows[0]) if c not in columns]
    return "\n".join(",".join(r[i] for i in keep) for r in rows).encode()


def _digest(folder: Path, volatile: dict[str, tuple[str, ...]] | None = None) -> dict[str, str]:
    """Every visible file under ``folder`` (relative path -> sha256); hidden names (marker, temporaries) left out.

    JSON files are compared by content with floats to 9 digits (parallel sums differ in the last bit);
    ``volatile``: CSV file name -> columns left out (timings).
    """
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder)
        if p.is_file() and not any(part.startswith(".") for part in rel.parts):
            data = p.read_bytes()
            if p.suffix == ".json":
                data = json.dumps(_rounded(json.loads(data)), sort_keys=True).encode()
            elif volatile and p.name in volatile:  # CSV columns of timings
                data = _drop_columns(data, volatile[p.name])
            out[str(rel)] = hashlib.sha256(data).hexdigest()
    return out


class Sets:
    """Byte-exact sets of a deterministic verb: the label of the set a folder holds, or an assertion."""

    def __init__(self, verb: str, folder: Path, marker: bool = True, volatile: dict | None = None):
        self.verb, self.folder, self.marker, self.volatile, self.known = verb, folder, marker, volatile, {}

    def __call__(self) -> str:
        if self.marker:
            assert (self.folder / MARKER).is_file() and read_marker(self.folder)["verb"] == self.verb
        else:  # recognised by its names
            assert not (self.folder / MARKER).exists() and may_replace(self.folder, self.verb) == (True, "legacy")
        d = _digest(self.folder, self.volatile)
        if len(self.known) < 2:  # the first two complete runs name the sets
            label = "ab"[len(self.known)]
            assert d not in self.known.values(), "set A and set B are the same bytes: the test cannot tell them apart"
            self.known[label] = d
            return label
        for label, ref in self.known.items():
            if d == ref:
                return label
        changed = sorted(k for k in set(d) | set(self.known["a"]) if d.get(k) != self.known["a"].get(k))
        raise AssertionError(f"{self.folder} is neither set A nor set B (differs from A in {changed[:8]})")


def _png(path: Path) -> None:
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a whole PNG"


# -- virtual lab (deterministic: same seed, same bytes) ----------------------------------------------------


def _tiny_lab(tmp: Path) -> Path:
    import yaml

    doc = yaml.safe_load((PIPE / "virtual_lab.yaml").read_text())
    doc["tunnel"].update(flow_speeds_mps=[0.1, 0.2], cycles=2, grid={
        "theta_h_min_deg": [-30.0], "theta_k_max_deg": [-60.0], "frequency_hz": [0.5, 0.6], "phi_rad": [0.0]})
    doc["towing"].update(speeds_mps=[0.1, 0.2], headings=["forward"])
    path = tmp / "lab.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.mark.parametrize("facility", ["tunnel", "towing"])
def test_virtual_lab_campaign_killed_at_random_moments(facility, tmp_path):
    lab = _tiny_lab(tmp_path)
    out = tmp_path / "raw" / f"k-{facility}"
    base = ("virtual-lab", facility, str(out), "--params", str(lab))
    state = Sets("virtual-lab", out)
    kill_cycle(f"virtual-lab {facility}", tmp_path, {"a": (*base, "--seed", "1"), "b": (*base, "--seed", "2")},
               state, [out.parent])


def test_virtual_lab_pool_killed_at_random_moments(tmp_path):
    out = tmp_path / "trials" / "k-pool"
    base = ("virtual-lab", "pool", str(out), "--synthetic", "--best", "1", "--fps", "8", "--size", "320x180")
    state = Sets("virtual-lab", out)
    kill_cycle("virtual-lab pool", tmp_path, {"a": (*base, "--seed", "1"), "b": (*base, "--seed", "2")},
               state, [out.parent])


def test_diagnose_on_a_tiny_virtual_campaign_killed_at_random_moments(tmp_path):
    """test_kills.py's diagnose kill test needs the demo data; this one builds 24 tiny runs (fresh clones run it)."""
    import yaml
    from test_kills import _diagnosis_state

    lab = _tiny_lab(tmp_path)
    doc = yaml.safe_load(lab.read_text())
    doc["tunnel"].update(cycles=3, grid={"theta_h_min_deg": [-30.0, 0.0, 10.0], "theta_k_max_deg": [-60.0, -20.0],
                                         "frequency_hz": [0.5, 0.7], "phi_rad": [0.0]})
    lab.write_text(yaml.safe_dump(doc))
    env = _env(tmp_path)
    _run(env, tmp_path, "virtual-lab", "tunnel", str(tmp_path / "raw" / "dt"), "--params", str(lab))
    processed = tmp_path / "processed" / "dt.parquet"
    _run(env, tmp_path, "ingest", str(tmp_path / "raw" / "dt"), "--out", str(processed), "--quiet")
    out = tmp_path / "diagnosis" / "dt"
    base = ("diagnose", "--processed", str(processed), "--model", "ef", "--no-mlflow", "--no-figures", "--effects",
            "servo_lag", "--out", str(out))
    sizes = {}

    def state() -> str:
        n = _diagnosis_state(out)
        if n not in sizes and len(sizes) < 2:
            sizes[n] = "ab"[len(sizes)]
        return sizes[n]

    kill_cycle("diagnose", tmp_path, {"a": (*base, "--max-runs", "16"), "b": (*base, "--max-runs", "24")}, state,
               [out.parent], env=env)


# -- simulate, sensitivity (deterministic) -----------------------------------------------------------------

GAIT = ("theta_h_min_deg=-30", "theta_k_max_deg=-60", "frequency_hz=0.4", "alpha_rad=0,1,2,3")


def test_simulate_killed_at_random_moments(tmp_path):
    out = tmp_path / "sim" / "k"
    base = ("simulate", "--gait", *GAIT, "--out", str(out))
    state = Sets("simulate", out)
    kill_cycle("simulate", tmp_path, {"a": (*base, "--duration", "2"), "b": (*base, "--duration", "3")}, state,
               [out.parent])


def test_sensitivity_killed_at_random_moments(tmp_path):
    gaits = {"task": "turn", "model": "ef",
             "settings": {"task": {"task": "turn", "cap_s": 2.0, "target_yaw_deg": 20.0}},
             "solutions": [{"rank": 1, "params": {"theta_h_min_deg": -20.0, "theta_k_max_deg": -50.0,
                                                   "frequency_hz": 0.5, "alpha_rad": [0.0, 3.1, 0.0, 3.1]}},
                           {"rank": 2, "params": {"theta_h_min_deg": 0.0, "theta_k_max_deg": -30.0,
                                                   "frequency_hz": 0.4, "alpha_rad": [0.0, 1.0, 2.0, 3.0]}}]}
    path = tmp_path / "turn-ef.json"
    path.write_text(json.dumps(gaits))
    out = tmp_path / "sens" / "turn-ef"
    base = ("sensitivity", "--gaits", str(path), "--n", "2", "--out", str(out))
    state = Sets("sensitivity", out)
    kill_cycle("sensitivity", tmp_path, {"a": (*base, "--seed", "1"), "b": (*base, "--seed", "2")}, state,
               [out.parent])


# -- optimize: a folder and two files beside it ------------------------------------------------------------


def test_optimize_killed_at_random_moments(tmp_path):
    out = tmp_path / "gaits"
    folder = out / "straight-ef"
    base = ("optimize", "--task", "straight", "--model", "ef", "--params", str(PIPE / "gait.yaml"), "--robot",
            str(PIPE / "robot.yaml"), "--pop", "8", "--no-mlflow", "--out", str(out))
    sets = Sets("optimize", folder, volatile={"history.csv": ("seconds",)})

    def state() -> str:
        """The folder is one set; the two files beside it each whole, written after it (the gait file last)."""
        label = sets()
        best = (folder / "best.csv").read_text().splitlines()[1].split(",")
        metrics = json.loads((out / "straight-ef.metrics.json").read_text())
        gait = json.loads((out / "straight-ef.json").read_text())
        got = [(label, "folder"), ({1: "a", 2: "b"}[metrics["generations"]], "metrics"),
               ({1: "a", 2: "b"}[gait["settings"]["nsga2"]["n_gen"]], "gait file")]
        assert float(best[-1]) == metrics["best_score"] or got[1][0] != label, "metrics and folder disagree"
        assert [g for g, _ in got] in (["a"] * 3, ["b"] * 3), f"outputs of different runs: {got}"
        return label

    kill_cycle("optimize", tmp_path, {"a": (*base, "--gens", "1"), "b": (*base, "--gens", "2")}, state, [out])


# -- train, evaluate, tune (timings inside: checked by content) --------------------------------------------


def _train_state(folder: Path) -> str:
    import torch

    assert read_marker(folder)["verb"] == "train"
    summary = json.loads((folder / "metrics.json").read_text())
    summary = summary.get("summary", summary)
    cfg = json.loads((folder / "config.json").read_text())
    history = (folder / "history.csv").read_text().strip().splitlines()[1:]
    json.loads((folder / "model.json").read_text())
    json.loads((folder / "split.json").read_text())
    torch.load(folder / "weights.pt", map_location="cpu", weights_only=False)
    _png(folder / "learning_curve.png")
    epochs = cfg["trainer"]["max_epochs"]
    assert len(history) == epochs and summary["epochs"] == epochs, "history, metrics and config disagree"
    return {1: "a", 2: "b"}[epochs]


@pytest.fixture(scope="module")
def learn_inputs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("learn")
    return small_parquet(tmp), tiny_learn_config(tmp)


def test_train_killed_at_random_moments(tmp_path, learn_inputs):
    data, cfg = learn_inputs
    out = tmp_path / "models" / "k"
    base = ("train", "--config", str(cfg), "--data", str(data), "--no-mlflow", "--out", str(out))
    kill_cycle("train", tmp_path, {"a": (*base, "--set", "trainer.max_epochs=1"),
                                   "b": (*base, "--set", "trainer.max_epochs=2")},
               lambda: _train_state(out), [out.parent])


def test_evaluate_killed_at_random_moments(tmp_path, learn_inputs):
    data, cfg = learn_inputs
    env = _env(tmp_path)
    models = {}
    for label, seed in (("a", 0), ("b", 1)):
        models[label] = tmp_path / "models" / label
        _run(env, tmp_path, "train", "--config", str(cfg), "--data", str(data), "--no-mlflow", "--set",
             "trainer.max_epochs=1", "--set", f"trainer.seed={seed}", "--out", str(models[label]))
    metrics = tmp_path / "metrics" / "leg_models.json"
    figures = tmp_path / "reports" / "leg_models"
    figure_sets = Sets("evaluate", figures, marker=False)  # a DVC plots folder: no marker file

    def runs(label):
        return ("evaluate", "--config", str(cfg), "--data", str(data), "--split", str(models["a"] / "split.json"),
                "--model", str(models[label]), "--out", str(metrics), "--figures", str(figures), "--no-mlflow")

    mse = {}

    def state() -> str:
        doc = json.loads(metrics.read_text())
        label = figure_sets()
        for p in figures.glob("*.png"):
            _png(p)
        key = json.dumps(doc["lstm"]["mse"], sort_keys=True)
        if len(mse) < 2 and label not in mse:  # the first two complete runs
            mse[label] = key
        # the metrics file is an output of its own (another folder): whole, of set A or B; the figures one set
        assert key in mse.values(), "the metrics file is neither set A's nor set B's"
        return label

    kill_cycle("evaluate", tmp_path, {"a": runs("a"), "b": runs("b")}, state, [metrics.parent, figures.parent],
               env=env)


def test_tune_killed_at_random_moments(tmp_path, learn_inputs):
    data, cfg = learn_inputs
    out = tmp_path / "tune" / "k"
    base = ("tune", "--config", str(cfg), "--data", str(data), "--study", "k", "--workers", "1", "--fresh",
            "--no-mlflow", "--out", str(out))

    def state() -> str:
        assert read_marker(out)["verb"] == "tune"
        best = json.loads((out / "best.json").read_text())
        rows = (out / "trials.csv").read_text().strip().splitlines()[1:]
        assert best["n_trials_total"] == len(rows) and best["best"]["number"] < len(rows), "best.json, trials.csv"
        return {1: "a", 2: "b"}[len(rows)]

    kill_cycle("tune", tmp_path, {"a": (*base, "--n-trials", "1"), "b": (*base, "--n-trials", "2")}, state,
               [out.parent, tmp_path / ".optuna"])


def test_train_ensemble_killed_at_random_moments(tmp_path, learn_inputs):
    data, cfg = learn_inputs
    out = tmp_path / "models" / "ens"
    base = ("train-ensemble", "--config", str(cfg), "--data", str(data), "--no-mlflow", "--set",
            "trainer.max_epochs=1", "--quiet", "--out", str(out))

    def state() -> str:
        import torch

        assert read_marker(out)["verb"] == "train-ensemble"
        rec = json.loads((out / "ensemble.json").read_text())
        dirs = sorted(p.name for p in out.iterdir() if p.is_dir())
        assert dirs == [m["dir"] for m in rec["members"]], "ensemble.json and the member folders disagree"
        for d in dirs:
            json.loads((out / d / "model.json").read_text())
            torch.load(out / d / "weights.pt", map_location="cpu", weights_only=False)
        return {2: "a", 3: "b"}[len(dirs)]

    kill_cycle("train-ensemble", tmp_path, {"a": (*base, "--members", "2"), "b": (*base, "--members", "3")}, state,
               [out.parent])


def test_plan_campaign_killed_at_random_moments(tmp_path, learn_inputs):
    """The manifest and plan.md beside it are one set: the plan.md always describes the manifest there."""
    import math
    import tomllib

    data, cfg = learn_inputs
    env = _env(tmp_path)
    ens = tmp_path / "models" / "ens"
    _run(env, tmp_path, "train-ensemble", "--config", str(cfg), "--data", str(data), "--no-mlflow", "--set",
         "trainer.max_epochs=1", "--quiet", "--out", str(ens), "--members", "2")
    gaits = tmp_path / "straight-x.json"
    gaits.write_text(json.dumps({"task": "straight", "model": "x", "solutions": [
        {"rank": 1, "params": {"theta_h_min_deg": -40.0, "theta_k_max_deg": -70.0, "frequency_hz": 0.6,
                               "alpha_rad": [0.0, math.pi, math.pi, 0.0]}}]}))
    out = tmp_path / "plans" / "next.toml"
    base = ("plan-campaign", "--model", str(ens), "--gaits", str(gaits), "--out", str(out), "--date", "2026-01-02",
            "--set", "n_candidates=24", "--set", "swim_s=4", "--set", "region_points_per_cycle=6")

    def state() -> str:
        runs = tomllib.loads(out.read_text())["runs"]
        header = (out.parent / "plan.md").read_text().splitlines()[0]
        assert header.startswith(f"# Plan next: {len(runs)} runs,"), f"plan.md {header!r} beside {len(runs)} runs"
        assert not any(k in r for r in runs for k in ("loadcell", "motion", "mcap"))
        return {2: "a", 3: "b"}[len(runs)]

    kill_cycle("plan-campaign", tmp_path, {"a": (*base, "--n-runs", "2"), "b": (*base, "--n-runs", "3")}, state,
               [out.parent], env=env)


# -- interpolate (one Parquet file) --------------------------------------------------------------------------


def test_interpolate_killed_at_random_moments(tmp_path):
    import pyarrow.parquet as pq
    from ingest_fixtures import RunPlan, write_campaign

    raw = write_campaign(tmp_path / "raw" / "k1", [RunPlan(f"r{i}", flow_speed=v, seed=i)
                                                  for i, v in enumerate((0.0, 0.1, 0.2, 0.3))])
    processed = tmp_path / "processed" / "k1.parquet"
    env = _env(tmp_path)
    _run(env, tmp_path, "ingest", str(raw), "--out", str(processed), "--quiet")
    out = tmp_path / "processed" / "interp" / "k1.parquet"

    def state() -> str:
        meta = json.loads(pq.read_schema(out).metadata[b"workbench"])
        pq.read_table(out)  # whole
        speeds = meta["interpolation"]["params"]["speeds_mps"]
        return {(0.05,): "a", (0.05, 0.15, 0.25): "b"}[tuple(speeds)]

    base = ("interpolate", str(processed), "--out", str(out))
    kill_cycle("interpolate", tmp_path, {"a": (*base, "--speeds", "0.05"),
                                         "b": (*base, "--speeds", "0.05", "0.15", "0.25")}, state, [out.parent],
               env=env)


# -- report (three files in a shared folder) -----------------------------------------------------------------


def _results(ds: Path, lstm_mse: float) -> Path:
    ch = ["fx_n", "fy_n", "fz_n", "tx_nm", "ty_nm", "tz_nm"]
    path = ds / "metrics" / "leg_models.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({m: {"mse": {c: v for c in ch}, "r2": {c: 0.8 for c in ch},
                                    "mse_by_flow_speed": {"0.10": {c: v for c in ch}}}
                                for m, v in (("ef", 0.04), ("lstm", lstm_mse))}))
    return ds


def test_report_killed_at_random_moments(tmp_path):
    dsets = {"a": _results(tmp_path / "ds-a", 0.01), "b": _results(tmp_path / "ds-b", 0.02)}
    out = tmp_path / "datasets" / "reports"
    (out / "leg_models").mkdir(parents=True)  # another verb's output shares the folder
    (out / "leg_models" / "mse_boxplot.png").write_bytes(b"\x89PNG\r\n\x1a\nother verb")
    ratio = {"a": 0.25, "b": 0.5}  # lstm / ef MSE, what each set's three files must all say

    def state() -> str:
        head = json.loads((out / "headline.json").read_text())
        label = {v: k for k, v in ratio.items()}[head["lstm_over_ef_mse"]["fz"]]
        md = (out / "report.md").read_text()
        page = (out / "report.html").read_text()
        assert f"{ratio[label]:.3f}" in md and f"{ratio[label]:.3f}" in page, "report files from different runs"
        assert page.rstrip().endswith("</html>")
        assert (out / "leg_models" / "mse_boxplot.png").read_bytes().endswith(b"other verb")
        return label

    def runs(label):
        return ("report", "--datasets", str(dsets[label]), "--out", str(out), "--no-mlflow")

    kill_cycle("report", tmp_path, {"a": runs("a"), "b": runs("b")}, state, [out])


# -- campaign add (the registry, then dvc add; the raw folder never touched) ---------------------------------


def test_campaign_add_killed_at_random_moments(tmp_path):
    from ingest_fixtures import RunPlan, tree_hash, write_campaign

    from workbench.ingest.registry import load_registry

    root = tmp_path / "proj"
    (root / "datasets" / "raw").mkdir(parents=True)
    (root / "pipelines").mkdir()
    (root / "pipelines" / "campaigns.yaml").write_text("tunnel:\n  - demo-tunnel\ntowing: []\n")
    subprocess.run(["git", "init", "-q"], cwd=root, check=True)
    subprocess.run([sys.executable, "-m", "dvc", "init", "-q"], cwd=root, check=True)
    env = project_env(root)
    names = [f"tunnel-k{i}" for i in range(KILLS + 1)]
    folders = {n: write_campaign(root / "datasets" / "raw" / n, [RunPlan("r1"), RunPlan("r2", flow_speed=0.2)])
               for n in names}
    hashes = {n: tree_hash(f) for n, f in folders.items()}

    def tracked(name: str) -> bool:
        dvc_file = root / "datasets" / "raw" / f"{name}.dvc"
        return dvc_file.is_file() and f"path: {name}" in dvc_file.read_text()

    full = _run(env, root, "campaign", "add", str(folders[names[0]]))
    assert load_registry(root)["tunnel"] == ["demo-tunnel", names[0]] and tracked(names[0])
    survived = 0
    for name, delay in zip(names[1:], _moments("campaign add", full, KILLS), strict=True):
        before = load_registry(root)["tunnel"]
        rc = kill_after(delay, "campaign", "add", str(folders[name]), env=env, cwd=root)
        survived += rc is None
        after = load_registry(root)["tunnel"]  # whole: it parses
        assert after in (before, [*before, name]), after
        assert tree_hash(folders[name]) == hashes[name], f"{name}: the raw folder changed"
        _run(env, root, "campaign", "add", str(folders[name]))  # the next add completes what the kill cut
        assert load_registry(root)["tunnel"] == [*before, name] and tracked(name)
        assert tree_hash(folders[name]) == hashes[name]
    st = subprocess.run([sys.executable, "-m", "dvc", "status", "--json"], cwd=root, capture_output=True, text=True,
                        env=env)
    assert st.returncode == 0 and json.loads(st.stdout or "{}") == {}, st.stdout + st.stderr
    assert leftovers(root / "pipelines") == [] and leftovers(root / "datasets" / "raw") == []
    _count("campaign add", survived, KILLS)
    assert survived >= 1


# -- acquire (a raw capture: whatever was stored is a valid prefix of what the device sent) -------------------


def test_acquire_killed_at_random_moments(tmp_path):
    import threading
    import tty

    from test_acquire import capture

    from workbench.contract.serial import FRAME_SIZE, decode_frames
    from workbench.ingest.readers.base import ReadSpec
    from workbench.ingest.readers.bin_reader import BinReader

    env = _env(tmp_path)
    sent = capture(n=4000)
    rng = random.Random(f"{SEED}-acquire")
    survived = 0
    for k in range(KILLS):
        master, slave = os.openpty()
        tty.setraw(slave)
        stop = threading.Event()

        def feed(master=master, stop=stop):
            time.sleep(0.5)
            for i in range(0, len(sent), 1000):
                if stop.is_set():
                    return
                os.write(master, sent[i:i + 1000])
                time.sleep(0.01)

        out = tmp_path / f"r{k}.loadcell.bin"
        proc = subprocess.Popen([sys.executable, "-m", "workbench.cli", "acquire", "--port", os.ttyname(slave),
                                 "--out", str(out), "--stall-s", "0"], cwd=tmp_path, env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        feeder = threading.Thread(target=feed, daemon=True)
        try:
            deadline = time.monotonic() + 120
            while not (out.exists() and out.stat().st_size >= 20 * FRAME_SIZE):
                assert proc.poll() is None and time.monotonic() < deadline, "acquire did not start recording"
                if out.exists() and not feeder.is_alive() and feeder.ident is None:
                    feeder.start()
                time.sleep(0.02)
            time.sleep(rng.uniform(0.0, 1.5))
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            survived += 1
        finally:
            stop.set()
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            os.close(master)
            os.close(slave)
        data = out.read_bytes()
        assert data == sent[:len(data)], "the capture is not what the device sent"
        frames = decode_frames(data)
        assert len(frames) == len(data) // FRAME_SIZE and frames.dropped_bytes == len(data) % FRAME_SIZE
        lc = BinReader(out, "loadcell", ReadSpec(run="r1", facility="water_tunnel", calibration=np.eye(6))).read()
        assert len(lc["loadcell"].time_s) == len(frames)
        r = subprocess.run([sys.executable, "-m", "workbench.cli", "acquire", "--port", "loop://", "--out", str(out)],
                           cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
        assert r.returncode == 2 and "never overwritten" in r.stderr and out.read_bytes() == data
    _count("acquire", survived, KILLS)
