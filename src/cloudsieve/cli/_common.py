"""Small helpers shared by the IO subcommands (argument types)."""

from __future__ import annotations

import argparse


def positive_int(text: str) -> int:
    """argparse type: an integer > 0; accepts 1_000_000 and 1e6."""
    try:
        value = int(float(text.replace("_", ""))) if any(c in text for c in "eE.") else int(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {value}")
    return value


FORMATS = ("las", "laz", "copc", "ply", "e57", "xyz")
