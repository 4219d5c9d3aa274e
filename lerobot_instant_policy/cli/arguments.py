"""Argument types the command lines share (``argparse`` ``type=`` callables)."""

from __future__ import annotations

import argparse


def xyz(text: str) -> tuple[float, float, float]:
    """``"x,y,z"`` → three floats; ``argparse.ArgumentTypeError`` for any other count."""
    values = tuple(float(x) for x in text.split(","))
    if len(values) != 3:
        raise argparse.ArgumentTypeError(f"expected x,y,z, got {text!r}")
    return values
