import subprocess
import sys
import time

from workbench.cli import main


def test_help_is_fast_and_lists_verbs():
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "workbench.cli", "--help"], capture_output=True, text=True)
    elapsed = time.perf_counter() - t0
    assert out.returncode == 0
    assert "workbench" in out.stdout
    # heavy libraries must not be imported by --help
    probe = subprocess.run(
        [sys.executable, "-c",
         "import sys, workbench.cli as c; c.build_parser(); "
         "print(sorted(m for m in ('torch','lightning','mlflow','cv2') if m in sys.modules))"],
        capture_output=True, text=True)
    assert probe.stdout.strip() == "[]", probe.stdout + probe.stderr
    assert elapsed < 10


def test_no_verb_prints_help(capsys):
    assert main([]) == 0
    assert "usage" in capsys.readouterr().out
