"""One rule for the manifests' ids (campaign runs, pool trials): the first entry of an id is kept, a repeat is an error."""

from __future__ import annotations

from typing import Callable, Iterable, TypeVar

T = TypeVar("T")


def first_of_each_id(parsed: Iterable[tuple[int, T | None]], on_repeat: Callable[[int, T], None]) -> list[T]:
    """The parsed entries in order, each ``id`` once: the first is kept, a repeat goes to ``on_repeat(i, entry)``.

    ``parsed``: ``(index in the file, entry or None)``; None (an entry that did not parse) is skipped.
    Entries are consumed in order, so errors collected while parsing and repeats keep the file's order.
    """
    out: list[T] = []
    seen: set = set()
    for i, entry in parsed:
        if entry is None:
            continue
        if entry.id in seen:
            on_repeat(i, entry)
            continue
        seen.add(entry.id)
        out.append(entry)
    return out
