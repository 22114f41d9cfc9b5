"""Terminal output: progress bars and status lines (rich), quiet when not on a terminal."""

from __future__ import annotations

import sys
from contextlib import contextmanager
from typing import Iterator


def info(msg: str) -> None:
    """A status line on stderr (stdout stays for machine-readable output)."""
    print(msg, file=sys.stderr, flush=True)


@contextmanager
def progress(description: str, total: float | None = None, unit: str = "") -> Iterator["_Task"]:
    """A progress bar on a terminal, a few plain lines elsewhere (logs, CI)."""
    if sys.stderr.isatty():
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("{task.fields[status]}"), TimeElapsedColumn(), TimeRemainingColumn(),
                      transient=False) as prog:
            task = prog.add_task(description, total=total, status="")
            yield _Task(lambda adv, status: prog.update(task, advance=adv, status=status or ""))
    else:
        state = {"done": 0.0, "last_pct": -100.0}

        def update(adv, status):
            state["done"] += adv
            pct = 100.0 * state["done"] / total if total else 0.0
            if total and (pct - state["last_pct"] >= 25 or state["done"] >= total):
                state["last_pct"] = pct
                info(f"{description}: {state['done']:.0f}/{total:.0f}{unit} {status or ''}".rstrip())

        info(f"{description} ...")
        yield _Task(update)


class _Task:
    def __init__(self, fn):
        self._fn = fn

    def advance(self, n: float = 1, status: str | None = None) -> None:
        """Advance by n steps, optionally showing a short status."""
        self._fn(n, status)
