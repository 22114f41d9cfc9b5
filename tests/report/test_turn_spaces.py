"""The report's turn table: the paper's gait space beside per_side_range, pool against prediction, per model."""

import json

from workbench.report import headline, trials_section, turn_spaces

HEADER = "trial_id,model,solution,task,time_s,mae_x_m,radius_m,completed\n"


def _gait(path, space, f3s):
    sols = [{"rank": i + 1, "params": {}, "objectives": {"f1": 1.0, "f2": 0.0, "f3": f3}, "score": 1.0,
             "converged": True} for i, f3 in enumerate(f3s)]
    path.write_text(json.dumps({"task": "turn", "model": path.stem.split("-", 1)[1], "gait_space": space,
                                "solutions": sols}))


def _pool(datasets, name, labels, rows):
    (datasets / "scores" / name).mkdir(parents=True)
    (datasets / "scores" / name / "summary.json").write_text("{}")
    (datasets / "scores" / name / "scores.csv").write_text(HEADER + "".join(r + "\n" for r in rows))
    (datasets / "raw" / name).mkdir(parents=True)
    (datasets / "raw" / name / "truth.json").write_text(json.dumps({"settings": {"model_labels": labels}}))


def test_turns_by_gait_space_with_predictions(tmp_path):
    d = tmp_path / "datasets"
    (d / "gaits").mkdir(parents=True)
    _gait(d / "gaits" / "turn-ef.json", "paper", [50.0, 52.0])
    _gait(d / "gaits" / "turn-lstm.json", "paper", [31.0, 33.0])
    _gait(d / "gaits" / "turn-ef-sides.json", "per_side_range", [20.0, 24.0])
    _gait(d / "gaits" / "turn-lstm-sides.json", "per_side_range", [18.0, 30.0])
    _pool(d, "demo-pool", {"ef": "EF", "lstm": "FED-LSTM"}, [
        "ef-straight-1,EF,1,straight,40.0,0.3,,true",
        "ef-turn-1,EF,1,turn,60.0,,0.3,false", "ef-turn-2,EF,2,turn,60.0,,0.1,false",
        "lstm-turn-1,FED-LSTM,1,turn,60.0,,0.4,false", "lstm-turn-2,FED-LSTM,2,turn,60.0,,0.5,false"])
    _pool(d, "demo-pool-sides", {"ef": "EF", "lstm": "FED-LSTM"}, [
        "ef-sides-turn-1,EF-sides,1,turn,30.0,,0.12,true", "ef-sides-turn-2,EF-sides,2,turn,60.0,,0.2,false",
        "lstm-sides-turn-1,FED-LSTM-sides,1,turn,21.0,,0.08,true",
        "lstm-sides-turn-2,FED-LSTM-sides,2,turn,35.0,,0.1,true"])
    (caption, header, rows), notes = turn_spaces(d)
    assert header[:4] == ["gait space", "model", "finished", "mean pool time (s)"]
    by = {(r[0], r[1]): r for r in rows}
    assert [r[0] for r in rows] == ["paper", "paper", "per_side_range", "per_side_range"]
    assert by[("paper", "EF")][2:] == ["0/2", "60.0", "0.200", "51.0", "+9.0"]
    assert by[("per_side_range", "EF-sides")][2:] == ["1/2", "45.0", "0.160", "22.0", "+23.0"]
    assert by[("per_side_range", "FED-LSTM-sides")][2:] == ["2/2", "28.0", "0.090", "24.0", "+4.0"]
    assert len(notes) == 1 and "per_side_range" in notes[0]
    assert "FED-LSTM-sides gaits beat EF-sides gaits" in notes[0] and "paper's space: 0/4" in notes[0]
    sec = trials_section(d)
    assert any(t[0] == caption for t in sec.tables) and notes[0] in sec.paragraphs
    pool = headline(d)["pool_finished"]
    assert pool["turn_EF-sides"] == 1 and pool["turn_FED-LSTM-sides"] == 2 and pool["turn_EF"] == 0


def test_no_table_without_an_extended_space(tmp_path):
    d = tmp_path / "datasets"
    (d / "gaits").mkdir(parents=True)
    _gait(d / "gaits" / "turn-ef.json", "paper", [50.0])
    _pool(d, "demo-pool", {"ef": "EF"}, ["ef-turn-1,EF,1,turn,60.0,,0.3,false"])
    assert turn_spaces(d) is None
