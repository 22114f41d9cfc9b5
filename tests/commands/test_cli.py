"""The ``workbench`` command's surface: fast help that names every verb, and a described ``--help`` per verb."""

import argparse
import re
import subprocess
import sys
import time

import pytest

from workbench.cli import VERB_MODULES, build_parser, main


def _subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """Name -> parser of a parser's subcommands (empty when it has none)."""
    out = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            out.update(action.choices)
    return out


VERBS = _subcommands(build_parser())
#: every sub-verb as an argv prefix: ["virtual-lab", "pool"], ["campaign", "add"], ...
SUB_VERBS = [[v, s] for v, p in VERBS.items() for s in _subcommands(p)]


def test_every_verb_module_is_a_verb():
    # a verb module that exists but registers nothing (or a misspelt name) would leave a verb out of --help
    assert len(VERBS) >= 15
    assert sorted(VERBS) == sorted(m.replace("_", "-") for m in VERB_MODULES if m.replace("_", "-") in VERBS)
    for module in VERB_MODULES:
        try:
            __import__(f"workbench.commands.{module}")
        except ModuleNotFoundError as exc:
            assert exc.name == f"workbench.commands.{module}", exc  # only "not built yet" may leave a verb out
            continue
        assert module.replace("_", "-") in VERBS, f"workbench.commands.{module} registers no verb of its name"


def test_help_is_fast_and_lists_every_verb():
    t0 = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "workbench.cli", "--help"], capture_output=True, text=True)
    elapsed = time.perf_counter() - t0
    assert out.returncode == 0, out.stderr
    listed = out.stdout.split("positional arguments:")[-1]
    missing = [v for v in VERBS if f"\n    {v} " not in listed and f"\n    {v}\n" not in listed]
    assert not missing, f"workbench --help does not list {missing}:\n{out.stdout}"
    # heavy libraries must not be imported by --help
    probe = subprocess.run(
        [sys.executable, "-c",
         "import sys, workbench.cli as c; c.build_parser(); "
         "print(sorted(m for m in ('torch','lightning','mlflow','cv2') if m in sys.modules))"],
        capture_output=True, text=True)
    assert probe.stdout.strip() == "[]", probe.stdout + probe.stderr
    assert elapsed < 10


def _help_text(argv, capsys) -> str:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith(f"usage: workbench {' '.join(argv)}"), text[:200]
    return text


@pytest.mark.parametrize("verb", list(VERBS))
def test_verb_help_exits_0_with_a_description(verb, capsys):
    text = _help_text([verb], capsys)
    description = (VERBS[verb].description or "").split()
    assert len(description) >= 4, f"workbench {verb} has no description"
    assert " ".join(description[:4]) in " ".join(text.split())


@pytest.mark.parametrize("argv", SUB_VERBS, ids=" ".join)
def test_sub_verb_help_exits_0_with_a_description(argv, capsys):
    text = _help_text(argv, capsys)
    description = (_subcommands(VERBS[argv[0]])[argv[1]].description or "").split()
    assert len(description) >= 4, f"workbench {' '.join(argv)} has no description"
    assert " ".join(description[:4]) in " ".join(text.split())


def _example_lines(text: str) -> list[str]:
    return text.split("examples:", 1)[1].splitlines() if "examples:" in text else []


@pytest.mark.parametrize("argv", [[v] for v in VERBS] + SUB_VERBS, ids=" ".join)
def test_help_examples_are_one_command_a_line(argv, capsys):
    """A lost line break (a single backslash in a Python string) runs two example lines into one."""
    lines = _example_lines(_help_text(argv, capsys))
    # an option after a run of spaces mid-line: the continuation line was joined to the one before
    joined = [ln for ln in lines if re.search(r"\S {3,}--[a-z]", ln)]
    assert not joined, joined
    # a continued example ends with one backslash, and the next line carries on indented
    for ln, nxt in zip(lines, [*lines[1:], ""][:len(lines)], strict=True):
        if ln.rstrip().endswith("\\"):
            assert not ln.rstrip().endswith("\\\\") and nxt.startswith("      "), (ln, nxt)


def test_the_example_check_sees_a_joined_line():
    bad = "examples:\n  workbench diagnose --model ef       --out /tmp/x\n"
    assert [ln for ln in _example_lines(bad) if re.search(r"\S {3,}--[a-z]", ln)]


def test_no_verb_prints_help(capsys):
    assert main([]) == 0
    assert "usage" in capsys.readouterr().out


def test_diagnose_help_names_every_effect_of_the_library(capsys):
    """The library grows by entry points; the help must follow it (it listed 12 of 20 by hand before)."""
    from workbench.diagnose.library import registry

    text = " ".join(_help_text(["diagnose"], capsys).split())
    names = list(registry())
    assert len(names) >= 15
    missing = [n for n in names if n not in text.replace("- ", "")]
    assert not missing, missing
