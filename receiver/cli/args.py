"""Argument types shared by the commands (argparse only: the parsers must load nothing heavy)."""

from __future__ import annotations

import argparse


def seconds_up_to(limit_s: float):
    """An argparse type: seconds in (0, limit_s]."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not 0 < value <= limit_s:
            raise argparse.ArgumentTypeError(f"must be seconds in (0, {limit_s:g}], not {text!r}")
        return value
    return parse
