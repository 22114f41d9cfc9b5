"""What the user sees for a parameter fault or a solver that did not converge (issue 17.4), verb by verb.

A bad value on the command line or in a gaits file reaches the terminal as one line naming the file,
the gait or key, and the fault (a SettingError/ParamsError, no longer re-labelled as a contract
fault), with exit status 2 and no output folder; a swim that did not converge where a result needs
one is a ConvergenceError.
"""

import json

import pytest
import yaml

from workbench.cli import main


def _gaits_file(path, frequency_hz=0.5, **settings):
    doc = {"task": "straight", "model": "ef", "solutions": [
        {"rank": 1, "params": {"theta_h_min_deg": -20.0, "theta_k_max_deg": -50.0, "frequency_hz": 0.4,
                               "alpha_rad": [0.0, 0.0, 3.14, 3.14]}, "score": 1.0},
        {"rank": 2, "params": {"theta_h_min_deg": 10.0, "theta_k_max_deg": -20.0, "frequency_hz": frequency_hz,
                               "alpha_rad": [0.0, 3.14, 0.0, 3.14]}, "score": 2.0}],
           "settings": {"task": {"task": "straight", "cap_s": 1.0, "finish_distance_m": 2.0, **settings}}}
    path.write_text(json.dumps(doc))
    return path


def _error(capsys) -> str:
    """The error line: one, the last thing on stderr (progress lines may come before it), no traceback."""
    err = capsys.readouterr().err.strip()
    lines = err.splitlines()
    assert lines[-1].startswith("error: ") and sum(x.startswith("error: ") for x in lines) == 1, err
    assert "Traceback" not in err, err
    return lines[-1]


GAIT = ["theta_h_min_deg=-30", "theta_k_max_deg=-60", "frequency_hz=0.4", "alpha_rad=0"]


@pytest.mark.parametrize("gait,message", [
    (["theta_h_min_deg=-30", "theta_k_max_deg=-60", "frequency_hz=fast", "alpha_rad=0"],
     "error: --gait frequency_hz: 'fast' is not a number (or list of numbers)"),
    (["theta_h_min_deg=-30", "theta_k_max_deg=-60", "frequency_hz=0", "alpha_rad=0"],
     "error: gait 1: gait parameters must be finite with positive frequency"),
])
def test_simulate_a_bad_command_line_gait_names_the_option_or_gait(gait, message, tmp_path, capsys):
    assert main(["simulate", "--gait", *gait, "--duration", "1", "--out", str(tmp_path / "s")]) == 2
    assert _error(capsys) == message
    assert not (tmp_path / "s").exists()


def test_simulate_a_bad_value_in_a_gaits_file_names_the_file_and_the_solution(tmp_path, capsys):
    gaits = _gaits_file(tmp_path / "straight-ef.json", frequency_hz=-0.6)
    # the good command-line gait comes after the file's: the error still names the file's solution rank 2
    assert main(["simulate", "--gaits", str(gaits), "--gait", *GAIT, "--duration", "1",
                 "--out", str(tmp_path / "s")]) == 2
    assert _error(capsys) == f"error: {gaits}, straight-ef #2: gait parameters must be finite with positive frequency"
    assert not (tmp_path / "s").exists()
    (gaits.parent / "text.json").write_text(gaits.read_text().replace("-0.6", '"fast"'))
    assert main(["simulate", "--gaits", str(gaits.parent / "text.json"), "--out", str(tmp_path / "s")]) == 2
    err = _error(capsys)
    assert err.startswith(f"error: {gaits.parent / 'text.json'}, straight-ef #2: gait parameters must be numbers")


def test_sensitivity_names_the_gaits_file_and_the_key_or_gait(tmp_path, capsys):
    bad_key = _gaits_file(tmp_path / "key.json", finish_distanc_m=1.0)
    assert main(["sensitivity", "--gaits", str(bad_key), "--n", "2", "--out", str(tmp_path / "o")]) == 2
    err = _error(capsys)
    assert err.startswith(f"error: {bad_key}, settings.task.finish_distanc_m: unknown setting") and "finish_distance_m" in err
    bad_sim = _gaits_file(tmp_path / "sim.json")
    doc = json.loads(bad_sim.read_text())
    doc["settings"]["simulation"] = {"max_iter": "many"}      # the scheme the gaits were optimised with
    bad_sim.write_text(json.dumps(doc))
    assert main(["sensitivity", "--gaits", str(bad_sim), "--n", "2", "--out", str(tmp_path / "o")]) == 2
    assert _error(capsys).startswith(f"error: {bad_sim}, settings.simulation.max_iter: must be")
    bad_gait = _gaits_file(tmp_path / "gait.json", frequency_hz=0.0)
    assert main(["sensitivity", "--gaits", str(bad_gait), "--n", "2", "--out", str(tmp_path / "o")]) == 2
    assert _error(capsys) == f"error: {bad_gait}, straight-ef #2: gait parameters must be finite with positive frequency"
    assert not (tmp_path / "o").exists()


def test_sensitivity_refuses_a_nominal_swim_that_did_not_converge(tmp_path, capsys):
    robot = yaml.safe_load(open("pipelines/robot.yaml"))
    robot["simulation"].update(max_iter=1, tol_mps=1e-12)      # one iteration per window cannot reach 1e-12
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump(robot))
    gaits = _gaits_file(tmp_path / "straight-ef.json")
    assert main(["sensitivity", "--gaits", str(gaits), "--robot", str(tmp_path / "robot.yaml"), "--n", "2",
                 "--out", str(tmp_path / "o")]) == 2
    err = _error(capsys)
    assert err.startswith("error: the nominal robot's simulation did not converge for straight-ef #1, straight-ef #2")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("argv,message", [
    (["--pop", "2"], "error: --pop/--gens/--seed: nsga2 needs pop_size >= 4 and n_gen >= 1"),
    (["--workers", "0"], "error: --workers: workers must be a positive integer or 'auto', not '0'"),
    (["--label", "a/b"], "error: --label: 'a/b' is not a file-name-safe name (letters, digits, '-' and '_', "
                         "e.g. lstm16)"),
])
def test_optimize_names_the_option_at_fault(argv, message, tmp_path, capsys):
    assert main(["optimize", "--task", "straight", *argv, "--out", str(tmp_path / "g"), "--no-mlflow"]) == 2
    assert _error(capsys) == message
    assert not (tmp_path / "g").exists()


@pytest.mark.parametrize("size,message", [
    ("big", "error: --size: must look like 960x540, got 'big'"),
    ("10x10", "error: command line (--seed, --size): width_px, height_px must be >= 64 and fps positive"),
])
def test_pool_names_the_option_at_fault(size, message, tmp_path, capsys):
    assert main(["virtual-lab", "pool", str(tmp_path / "p"), "--synthetic", "--size", size, "--seed", "1"]) == 2
    assert _error(capsys) == message
    assert not (tmp_path / "p").exists()
