"""DVC sees every input: each stage's deps cover every workbench module its command can run (issue 15.1).

The module list is derived from the imports (tests/stage_deps.py explains the rule); dvc.yaml is
hand-written for readability, and this test keeps it honest.
"""
from __future__ import annotations

import stage_deps


def test_import_analysis_follows_function_level_and_plugin_imports():
    # things a hand-kept list missed before: train runs hydro/motion.py and hydro/legmodel.py
    train = stage_deps.stage_code("workbench train --data x --out y")
    names = {str(p.relative_to(stage_deps.ROOT)) for p in train}
    assert "workbench/hydro/motion.py" in names
    assert "workbench/hydro/legmodel.py" in names
    assert "workbench/errors.py" in names and "workbench/cli.py" in names
    # other verbs' modules are not part of a stage's code (cli.py only builds their parsers) ...
    assert "workbench/commands/ui.py" not in names
    # ... but another verb's module that the stage's verb imports is (diagnose -> diagnose_trials, which
    # swims trials through simulate's helpers; sensitivity -> simulate): a hole the rule once had
    diagnose = {str(p.relative_to(stage_deps.ROOT)) for p in stage_deps.stage_code("workbench diagnose --processed x")}
    assert {"workbench/commands/diagnose_trials.py", "workbench/commands/simulate.py"} <= diagnose
    assert "workbench/commands/ui.py" not in diagnose and "workbench/commands/train.py" not in diagnose
    sensitivity = stage_deps.stage_code("workbench sensitivity --gaits x")
    assert stage_deps.PKG / "commands" / "simulate.py" in sensitivity
    # ... and a verb that does not exist gives nothing rather than a guess
    assert stage_deps.stage_code("echo hello") == set()


def test_every_stage_dep_list_covers_its_code():
    missing = stage_deps.missing_deps()
    lines = [f"{stage}: {', '.join(files)}" for stage, files in missing.items()]
    assert not missing, ("dvc.yaml stages miss modules their command imports (add the files or their "
                         "folders to the stage's deps; `python tests/stage_deps.py` lists them):\n"
                         + "\n".join(lines))
