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


def number_in(lo: float, hi: float, unit: str = "", *, low_open: bool = False):
    """An argparse type: a finite number in [lo, hi] ((lo, hi] with `low_open`); the bounds
    are physical (a board square of 1e300 mm or a tone of 1e-10 Hz is a typo, and would
    overflow or take forever further on)."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        inside = (lo < value if low_open else lo <= value) and value <= hi  # NaN fails both
        if not inside:
            raise argparse.ArgumentTypeError(
                f"must be {'over' if low_open else 'at least'} {lo:g} and at most {hi:g}"
                f"{' ' + unit if unit else ''}, not {text!r}")
        return value
    return parse


def whole_in(lo: int, hi: int):
    """An argparse type: a whole number in [lo, hi]."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"must be a whole number {lo}..{hi}, not {text!r}")
        return value
    return parse


# Frame counts an option may ask for: a day of video at 1,000 frames/s is under 10^8.
MAX_FRAMES = 10**9
# Upper bound of --max-pixels: a 16-bit OpenCV image dimension squared (32767^2 ~ 1.07e9).
MAX_PIXELS = 1 << 30
