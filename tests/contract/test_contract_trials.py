"""trials.toml parsing: a valid folder, and every violation collected (folder-level vs trial-level)."""

import pytest

from workbench.contract.trials import check_trials, load_trials
from workbench.errors import ContractError

GOOD = """\
schema = "workbench/trials@1"
id = "pool-2025-04"

[tank]
width_m = 4.0
length_m = 5.0

[camera]
reference_px = [[620.8, 318.5], [500.6, 47.0], [159.4, 41.5], [19.2, 289.2]]
reference_m = [[0.0, 0.0], [4.0, 0.0], [4.0, 5.0], [0.0, 5.0]]

[robot]
head_marker = "red"
tail_marker = "blue"

[[trials]]
id = "lstm-straight-1"
task = "straight"
model = "FED-LSTM"
solution = 1
video = "videos/lstm-straight-1.mp4"
start_s = 0.0
"""


def make(tmp_path, text, videos=("lstm-straight-1.mp4",)):
    d = tmp_path / "pool"
    (d / "videos").mkdir(parents=True)
    for v in videos:
        (d / "videos" / v).write_bytes(b"x")
    (d / "trials.toml").write_text(text)
    return d


def trial(**kw):
    base = dict(id="t2", task="turn", model="EF", solution=2, video="videos/t2.avi", start_s=1.5)
    base.update(kw)
    lines = ["", "[[trials]]"]
    for k, v in base.items():
        if v is None:
            continue
        lines.append(f"{k} = {v!r}".replace("'", '"') if isinstance(v, str) else f"{k} = {v}")
    return "\n".join(lines) + "\n"


def test_valid_folder(tmp_path):
    d = make(tmp_path, GOOD + trial(), videos=("lstm-straight-1.mp4", "t2.avi"))
    folder, per_trial = load_trials(d)
    assert folder.id == "pool-2025-04" and folder.tank.width_m == 4.0
    assert folder.robot.head_marker == "red"
    assert [t.id for t in folder.trials] == ["lstm-straight-1", "t2"]
    t2 = folder.trial("t2")
    assert (t2.task, t2.model, t2.solution, t2.start_s) == ("turn", "EF", 2, 1.5)
    assert t2.video == d / "videos" / "t2.avi"
    assert t2.camera == folder.camera
    assert per_trial == {}


@pytest.mark.parametrize("edit, where", [
    (lambda s: s.replace("workbench/trials@1", "workbench/trials@9"), "schema"),
    (lambda s: s.replace('head_marker = "red"', 'head_marker = "orange"'), "head_marker"),
    (lambda s: s.replace('tail_marker = "blue"', 'tail_marker = "red"'), "must differ"),
    (lambda s: s.replace("width_m = 4.0", "width_m = -4.0"), "[tank]"),
    (lambda s: s.replace("[[0.0, 0.0], [4.0, 0.0], [4.0, 5.0], [0.0, 5.0]]", "[[0.0, 0.0], [4.0, 0.0]]"),
     "reference_m"),
    (lambda s: s.replace("[159.4, 41.5]", "[320.0, 180.0]").replace("[19.2, 289.2]", "[19.2, 318.5]"),
     "degenerate"),
    (lambda s: s.split("[[trials]]")[0], "no [[trials]]"),
    (lambda s: s + trial(id="lstm-straight-1", video="videos/lstm-straight-1.mp4"), "duplicate"),
])
def test_folder_level_violations(tmp_path, edit, where):
    d = make(tmp_path, edit(GOOD))
    folder, errors, _ = check_trials(d)
    assert errors and any(where in e.format() for e in errors), [e.format() for e in errors]
    with pytest.raises(ContractError):
        load_trials(d)


@pytest.mark.parametrize("entry, fault", [
    (trial(task="hover"), "task must be one of"),
    (trial(solution=0), "solution must be a positive integer"),
    (trial(start_s=-1.0), "start_s must be"),
    (trial(start_s=None), "start_s must be"),
    (trial(video="/abs/t2.mp4"), "absolute"),
    (trial(video="../outside.mp4"), "escapes"),
    (trial(video="videos/t2.mov"), ".mp4 or .avi"),
    (trial(video="videos/missing.mp4"), "not found"),
    (trial(model=""), "model must be"),
    (trial() + "reference_px = [[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [0.0, 10.0]]\n", "collinear"),
])
def test_trial_level_violations_spoil_only_that_trial(tmp_path, entry, fault):
    d = make(tmp_path, GOOD + entry, videos=("lstm-straight-1.mp4", "t2.avi"))
    folder, per_trial = load_trials(d)
    assert [t.id for t in folder.trials] == ["lstm-straight-1", "t2"]
    assert list(per_trial) == ["t2"]
    msg = per_trial["t2"][0].format()
    assert fault in msg and "trial t2" in msg and "trials.toml" in msg


def test_per_trial_camera_override(tmp_path):
    override = "reference_px = [[600.0, 300.0], [500.0, 50.0], [160.0, 40.0], [20.0, 290.0]]\n"
    d = make(tmp_path, GOOD + trial() + override, videos=("lstm-straight-1.mp4", "t2.avi"))
    folder, per_trial = load_trials(d)
    assert not per_trial
    assert folder.trial("t2").camera.reference_px[0] == (600.0, 300.0)
    assert folder.trial("t2").camera.reference_m == folder.camera.reference_m


def test_missing_folder_manifest_and_bad_toml(tmp_path):
    assert "does not exist" in check_trials(tmp_path / "nope")[1][0].format()
    (tmp_path / "empty").mkdir()
    assert "missing trials.toml" in check_trials(tmp_path / "empty")[1][0].format()
    d = make(tmp_path, "schema = ")
    assert "not valid TOML" in check_trials(d)[1][0].format()
