"""Bad input: each faulty trial fails with a clear one-line error, the others are still scored."""

import hashlib
import json
import re

import pytest
from trials_helpers import SMALL, fast_straight

from workbench.cli import main
from workbench.errors import DataError
from workbench.trials import ScoringSettings, run_scoring
from workbench.virtual_lab.pool import PoolSettings, generate_pool

EXPECTED = {
    "no-markers": "never found",
    "short-video": "video ends",
    "missing-video": "not found",
    "garbage-video": "cannot be opened",
    "late-start": "past the video's end",
    "bad-refs": "degenerate reference points",
}


@pytest.fixture(scope="module")
def bad_pool(tmp_path_factory):
    d = tmp_path_factory.mktemp("bad") / "bad-pool"
    trials = [fast_straight("ok-straight"), fast_straight("no-markers", markers=False),
              fast_straight("short-video", video_until_s=3.0)]
    generate_pool(d, trials, settings=PoolSettings(**SMALL, seed=5), progress=False)
    (d / "videos" / "garbage.mp4").write_bytes(bytes(range(256)) * 64)
    extra = """
[[trials]]
id = "missing-video"
task = "straight"
model = "EF"
solution = 4
video = "videos/missing.mp4"
start_s = 0.5

[[trials]]
id = "garbage-video"
task = "turn"
model = "EF"
solution = 5
video = "videos/garbage.mp4"
start_s = 0.5

[[trials]]
id = "late-start"
task = "straight"
model = "EF"
solution = 6
video = "videos/ok-straight.mp4"
start_s = 99.0

[[trials]]
id = "bad-refs"
task = "straight"
model = "EF"
solution = 7
video = "videos/ok-straight.mp4"
start_s = 0.53
reference_px = [[10.0, 10.0], [20.0, 20.0], [30.0, 30.0], [10.0, 50.0]]
"""
    with open(d / "trials.toml", "a") as fh:
        fh.write(extra)
    return d


def _digest(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def scored(bad_pool, tmp_path_factory):
    before = _digest(bad_pool)
    out = tmp_path_factory.mktemp("bad-out") / "scores"
    result, summary = run_scoring(bad_pool, out, ScoringSettings(workers=1, overlay=False, plots=False),
                                  show_progress=False)
    assert _digest(bad_pool) == before  # raw data never modified
    return result, summary, out


def test_good_trial_still_scored(scored):
    result, summary, out = scored
    assert [r.spec.id for r in result.results] == ["ok-straight"]
    assert summary["n_scored"] == 1 and summary["n_failed"] == len(EXPECTED)
    lines = (out / "scores.csv").read_text().splitlines()
    assert lines[0] == "trial_id,model,solution,task,time_s,mae_x_m,radius_m,completed"
    assert len(lines) == 2 and lines[1].startswith("ok-straight,EF,1,straight,")
    # switched-off plots and overlays still leave their folders (DVC outputs), saying why
    for sub, key in (("plots", "scoring.plots: false"), ("overlays", "scoring.overlay: false")):
        assert [p.name for p in (out / sub).iterdir()] == ["README.txt"]
        assert key in (out / sub / "README.txt").read_text()


@pytest.mark.parametrize("tid", sorted(EXPECTED))
def test_each_failure_is_one_clear_line(scored, tid):
    _, summary, out = scored
    failed = {f["trial_id"]: f["error"] for f in summary["failed"]}
    err = failed[tid]
    assert EXPECTED[tid] in err
    assert f"trial {tid}" in err and "\n" not in err
    assert re.search(r"(trials\.toml|\.mp4)", err)
    on_disk = json.loads((out / "summary.json").read_text())
    assert tid in {f["trial_id"] for f in on_disk["failed"]}


def test_cli_exit_status(bad_pool, tmp_path, capsys):
    out = tmp_path / "s1"
    assert main(["score-trials", str(bad_pool), "--out", str(out), "--no-overlay", "--no-plots",
                 "--workers", "1"]) == 0
    err = capsys.readouterr().err
    assert "scored 1 of 7 trials" in err and "FAILED no-markers" in err
    # --strict: outputs written, but the status says something failed
    out2 = tmp_path / "s2"
    assert main(["score-trials", str(bad_pool), "--out", str(out2), "--no-overlay", "--no-plots",
                 "--workers", "1", "--strict"]) == 2
    assert (out2 / "summary.json").exists()
    assert "6 trial(s) failed" in capsys.readouterr().err


def test_nothing_scored_is_an_error_and_keeps_the_old_result(bad_pool, tmp_path, capsys):
    out = tmp_path / "s"
    out.mkdir()
    (out / "scores.csv").write_text("previous\n")
    rc = main(["score-trials", str(bad_pool), "--out", str(out), "--no-overlay", "--no-plots", "--workers", "1",
               "--trial", "no-markers", "--trial", "late-start"])
    assert rc == 2
    assert "no trial could be scored" in capsys.readouterr().err
    assert (out / "scores.csv").read_text() == "previous\n"
    with pytest.raises(DataError):
        run_scoring(bad_pool, tmp_path / "x", ScoringSettings(workers=1), trial_ids=["garbage-video"],
                    show_progress=False)
    assert not (tmp_path / "x").exists()


def test_folder_level_faults_exit_non_zero(bad_pool, tmp_path, capsys):
    text = (bad_pool / "trials.toml").read_text()
    bad = tmp_path / "folder-bad"
    bad.mkdir()
    (bad / "videos").symlink_to(bad_pool / "videos")
    first = text.split("reference_px = ", 1)
    (bad / "trials.toml").write_text(first[0] + "reference_px = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]\n"
                                     + first[1].split("\n", 1)[1])
    assert main(["score-trials", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and "degenerate reference points" in err and "[camera]" in err
    assert not (tmp_path / "o").exists()
    assert main(["score-trials", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o")]) == 2


def test_refuses_to_overwrite_a_foreign_folder_or_write_into_raw(bad_pool, tmp_path, capsys):
    foreign = tmp_path / "home"
    foreign.mkdir()
    (foreign / "thesis.tex").write_text("precious")
    assert main(["score-trials", str(bad_pool), "--out", str(foreign)]) == 2
    assert (foreign / "thesis.tex").read_text() == "precious"
    assert main(["score-trials", str(bad_pool), "--out", str(bad_pool / "scores")]) == 2
    assert "never modified" in capsys.readouterr().err


def test_check_lists_every_manifest_problem(bad_pool, small_pool, tmp_path, capsys):
    assert main(["score-trials", str(bad_pool), "--out", str(tmp_path / "o"), "--check"]) == 2
    out = capsys.readouterr().out
    assert "trial missing-video" in out and "trial bad-refs" in out
    assert main(["score-trials", str(small_pool), "--out", str(tmp_path / "o"), "--check"]) == 0
    assert "valid (4 trials)" in capsys.readouterr().out
    assert not (tmp_path / "o").exists()
