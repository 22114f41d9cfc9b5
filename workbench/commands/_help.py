"""Shared argparse helpers for verb modules."""

from __future__ import annotations

import argparse


def add_verb(sub, name: str, help: str, description: str, examples: str) -> argparse.ArgumentParser:
    """Add a verb parser whose help ends with worked examples."""
    return sub.add_parser(
        name,
        help=help,
        description=description,
        epilog="examples:\n" + examples.rstrip() + "\n",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
