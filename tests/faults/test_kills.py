"""kill -9 at random moments of ingest, fit-drag, score-trials and diagnose: outputs stay complete sets.

Each test writes a first complete output (set A), then starts the real CLI in a subprocess that would
write a different set B and kills its process group with SIGKILL at random moments (seeded:
FAULT_SEED). After every kill the output must be set A or set B, whole (every file readable, the
files of one run together); after the next complete run no temporary may be left. Kill moments
spread over the run's measured length, one early in start-up.
"""

from __future__ import annotations

import json
import os
import random
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from faults_helpers import ROOT, cli, kill_after, kill_moments, leftovers, timed_cli
from ingest_fixtures import RunPlan, write_campaign

from workbench.atomic import read_marker

pytestmark = [pytest.mark.faults, pytest.mark.slow]

SEED = int(os.environ.get("FAULT_SEED", "16"))
KILLS = int(os.environ.get("FAULT_KILLS", "3"))


def _rng(name: str) -> random.Random:
    return random.Random(f"{SEED}-{name}")


# -- ingest ----------------------------------------------------------------------------------------------


def _ingest_state(out: Path) -> float:
    """The cutoff the Parquet was made with (set A or B); the Parquet must be whole."""
    meta = json.loads(pq.read_schema(out).metadata[b"workbench"])
    pq.read_table(out)  # whole
    return meta["params"]["lowpass_cutoff_hz"]


def test_ingest_killed_at_random_moments(tmp_path):
    raw = write_campaign(tmp_path / "raw" / "k1", [RunPlan(f"r{i}", flow_speed=0.05 * i, cycles=6)
                                                  for i in range(1, 7)])
    out = tmp_path / "processed" / "k1.parquet"
    qual = out.with_name("k1.quality.json")
    params_b = tmp_path / "b.yaml"
    params_b.write_text("ingest:\n  lowpass_cutoff_hz: 5.0\n")
    timed_cli("ingest", str(raw), "--out", str(out), "--quiet")                   # set A: 6 Hz
    full = timed_cli("ingest", str(raw), "--out", str(tmp_path / "probe.parquet"), "--quiet", "--force",
                     "--params", str(params_b))
    params = {6.0: [], 5.0: ["--params", str(params_b)]}
    survived = 0
    for delay in kill_moments(_rng("ingest"), full, KILLS):
        other = 5.0 if _ingest_state(out) == 6.0 else 6.0   # each kill aims at the set not there now
        rc = kill_after(delay, "ingest", str(raw), "--out", str(out), "--quiet", "--force", *params[other])
        survived += rc is None
        # whole, and the next ingest with the parameters it holds finds it up to date with its report in line
        cutoff = _ingest_state(out)
        r = cli("ingest", str(raw), "--out", str(out), "--quiet", *params[cutoff])
        assert r.returncode == 0 and "up to date" in r.stderr, r.stderr
        meta = json.loads(pq.read_schema(out).metadata[b"workbench"])
        assert json.loads(qual.read_text()) == meta["quality"]
    timed_cli("ingest", str(raw), "--out", str(out), "--quiet", "--force")
    assert leftovers(out.parent) == [], "temporaries of killed runs were not swept"
    print(f"ingest: {survived} of {KILLS} kills landed inside a run")
    assert survived >= 1, "no kill landed inside a run"


def test_a_kill_between_parquet_and_report_is_mended_by_the_next_ingest(tmp_path):
    """The issue's window, planted: the new Parquet beside the old quality.json."""
    raw = write_campaign(tmp_path / "raw" / "k2", [RunPlan("r1"), RunPlan("r2", flow_speed=0.2)])
    out = tmp_path / "k2.parquet"
    qual = out.with_name("k2.quality.json")
    timed_cli("ingest", str(raw), "--out", str(out), "--quiet")
    stale = json.loads(qual.read_text())
    stale["runs_total"] = 99
    qual.write_text(json.dumps(stale))
    r = cli("ingest", str(raw), "--out", str(out), "--quiet")
    assert r.returncode == 0 and "up to date" in r.stderr
    assert json.loads(qual.read_text())["runs_total"] == 2


# -- fit-drag --------------------------------------------------------------------------------------------


def _drag_state(out: Path) -> str:
    """Which campaign the folder's set came from; the three files must all be there and agree."""
    assert read_marker(out)["verb"] == "fit-drag"
    doc = json.loads((out / "drag.json").read_text())
    md = (out / "drag.md").read_text()
    assert (out / "drag.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"`{doc['source']}`" in md, "drag.md and drag.json come from different runs"
    return Path(doc["source"]).name


def test_fit_drag_killed_at_random_moments(tmp_path):
    from towing_fixture import PAPER, write_raw_towing_campaign

    a = write_raw_towing_campaign(tmp_path / "raw" / "tow-a")
    b = write_raw_towing_campaign(tmp_path / "raw" / "tow-b", coeffs={k: (2 * v[0], v[1], v[2]) for k, v in
                                                                      PAPER.items()}, seed=1)
    out = tmp_path / "drag" / "tow"
    timed_cli("fit-drag", str(a), "--out", str(out))
    full = timed_cli("fit-drag", str(b), "--out", str(tmp_path / "probe"))
    src = {"tow-a": a, "tow-b": b}
    survived = 0
    for delay in kill_moments(_rng("fit-drag"), full, KILLS):
        other = "tow-b" if _drag_state(out) == "tow-a" else "tow-a"
        rc = kill_after(delay, "fit-drag", str(src[other]), "--out", str(out))
        assert _drag_state(out) in ("tow-a", "tow-b")
        survived += rc is None
    timed_cli("fit-drag", str(a), "--out", str(out))
    assert _drag_state(out) == "tow-a" and leftovers(out.parent) == []
    print(f"test_fit_drag_killed_at_random_moments: {survived} of {KILLS} kills landed inside a run")
    assert survived >= 1


# -- score-trials ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def pool(tmp_path_factory):
    from trials_helpers import SMALL, fast_straight, fast_turn

    from workbench.virtual_lab.pool import PoolSettings, generate_pool

    out = tmp_path_factory.mktemp("pools") / "kill-pool"
    generate_pool(out, [fast_straight("ef-straight-1", "EF"), fast_turn("lstm-turn-1", "FED-LSTM")],
                  settings=PoolSettings(**SMALL, seed=5), progress=False)
    return out


def _scores_state(out: Path) -> int:
    assert read_marker(out)["verb"] == "score-trials"
    summary = json.loads((out / "summary.json").read_text())
    rows = (out / "scores.csv").read_text().strip().splitlines()[1:]
    assert len(rows) == summary["n_scored"], "scores.csv and summary.json come from different runs"
    assert (out / "comparison.md").is_file() and (out / "plots").is_dir() and (out / "overlays").is_dir()
    assert len(list((out / "trajectories").glob("*.parquet"))) == summary["n_scored"]
    return summary["n_scored"]


def test_score_trials_killed_at_random_moments(pool, tmp_path):
    out = tmp_path / "scores" / "pool"
    one = ("score-trials", str(pool), "--out", str(out), "--trial", "ef-straight-1", "--no-overlay", "--workers", "1")
    timed_cli(*one)
    full = timed_cli("score-trials", str(pool), "--out", str(tmp_path / "probe"), "--workers", "2")
    both = ("score-trials", str(pool), "--out", str(out), "--workers", "2")
    survived = 0
    for delay in kill_moments(_rng("score-trials"), full, KILLS):
        rc = kill_after(delay, *(both if _scores_state(out) == 1 else one))
        assert _scores_state(out) in (1, 2)
        survived += rc is None
    timed_cli(*one)
    assert _scores_state(out) == 1 and leftovers(out.parent) == []
    print(f"test_score_trials_killed_at_random_moments: {survived} of {KILLS} kills landed inside a run")
    assert survived >= 1


# -- diagnose --------------------------------------------------------------------------------------------

DEMO = ROOT / "datasets" / "processed" / "demo-tunnel.parquet"


def _diagnosis_state(out: Path) -> int:
    """How many runs the diagnosis trained on (set A or B); its three outputs must all be whole."""
    assert read_marker(out)["verb"] == "diagnose"
    doc = json.loads((out / "diagnosis.json").read_text())
    json.loads((out / "augmented_model.json").read_text())
    assert (out / "report.md").read_text().strip()
    return doc["n_train_runs"] + len(doc["heldout_runs"])


@pytest.mark.skipif(not DEMO.is_file(), reason="needs the demo's processed tunnel data (dvc repro)")
def test_diagnose_killed_at_random_moments(tmp_path):
    out = tmp_path / "diagnosis" / "demo"
    base = ("diagnose", "--processed", str(DEMO), "--model", "ef", "--no-mlflow", "--no-figures",
            "--effects", "servo_lag")
    timed_cli(*base, "--out", str(out), "--max-runs", "16")
    n_a = _diagnosis_state(out)
    full = timed_cli(*base, "--out", str(tmp_path / "probe"), "--max-runs", "24")
    n_b = _diagnosis_state(tmp_path / "probe")
    assert n_a != n_b
    runs = {n_a: "16", n_b: "24"}
    survived = 0
    for delay in kill_moments(_rng("diagnose"), full, KILLS):
        other = n_b if _diagnosis_state(out) == n_a else n_a
        rc = kill_after(delay, *base, "--out", str(out), "--max-runs", runs[other])
        assert _diagnosis_state(out) in (n_a, n_b)
        survived += rc is None
    timed_cli(*base, "--out", str(out), "--max-runs", "16")
    assert _diagnosis_state(out) == n_a and leftovers(out.parent) == []
    print(f"test_diagnose_killed_at_random_moments: {survived} of {KILLS} kills landed inside a run")
    assert survived >= 1
