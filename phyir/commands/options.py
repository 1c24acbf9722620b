"""Validated numbers for command-line options: argparse ``type=`` factories used by every numeric
option of ``phyir`` and ``phyir-view`` (docs/robustness.md, "Numeric options").

Each factory returns a parser that accepts only finite values in a closed range, so ``nan``,
``inf``, ``1e309`` (which ``float`` reads as inf), ``0`` where it means nothing and absurd sizes
are refused by argparse in one line naming the option (``phyir insert: error: argument --fov:
expected a number in 10..150, got 'nan'``; exit 2) before anything runs.  ``float()``'s spellings
are accepted (``1e-3``, `` 2``, ``1_000``); hex floats and other words are not numbers.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def _fmt(x: float) -> str:
    return f"{x:g}"


def _parse_number(text: str, integer: bool) -> float:
    """``text`` as a finite number; an integer (``4``, ``4.0``, ``1e3``) when ``integer``."""
    try:
        x = float(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f"expected {'an integer' if integer else 'a number'}, "
                                         f"got {text!r}") from None
    if not math.isfinite(x):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    if integer and x != int(x):
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}")
    return x


def check_range(x: float, lo: float, hi: float, text: str) -> None:
    if not lo <= x <= hi:
        raise argparse.ArgumentTypeError(f"expected a number in {_fmt(lo)}..{_fmt(hi)}, got {text!r}")


def number(lo: float, hi: float, *, integer: bool = False) -> Callable[[str], float]:
    """A finite number in [lo, hi] (an ``int`` when ``integer``)."""
    def parse(text: str):
        x = _parse_number(text, integer)
        check_range(x, lo, hi, text)
        return int(x) if integer else x
    parse.__name__ = "integer" if integer else "number"  # argparse's "invalid <name> value"
    return parse


def numbers(count: int, lo: float, hi: float, what: str = "X,Y") -> Callable[[str], tuple[float, ...]]:
    """``count`` comma-separated finite numbers, each in [lo, hi] (``what`` names them: ``U,V``)."""
    def parse(text: str) -> tuple[float, ...]:
        parts = str(text).split(",")
        if len(parts) != count:
            raise argparse.ArgumentTypeError(f"expected {count} comma-separated numbers {what}, got {text!r}")
        vals = tuple(_parse_number(p, False) for p in parts)
        if not all(lo <= v <= hi for v in vals):
            raise argparse.ArgumentTypeError(f"expected numbers in {_fmt(lo)}..{_fmt(hi)}, got {text!r}")
        return vals
    parse.__name__ = "numbers"
    return parse


class ImagePoint(tuple):
    """``(u, v)`` of ``--at`` / ``--path`` as given: a pixel's column and row, or (``fraction``) the
    fractions of the panorama's width and height; :func:`to_pixels` makes pixels of either."""

    fraction: bool

    def __new__(cls, u: float, v: float, fraction: bool = False):
        point = super().__new__(cls, (u, v))
        point.fraction = fraction
        return point


POINT_HELP = ("pixel column U, row V from the top left (e.g. 512,400 in a 1024x512 panorama), or, when "
              "both are written with a dot and are in 0..1, fractions of the width and height "
              "(0.5,0.78: the middle column, 78%% of the way down)")


def image_point(limit: float) -> Callable[[str], ImagePoint]:
    """``U,V``: pixels (finite, within +-``limit``; the panorama's size is checked once it is
    loaded), or fractions of the width and height when both are in [0, 1] and written with a dot
    (``0.5,0.78``; ``0,1`` and ``1,0`` are pixels)."""
    pair = numbers(2, -limit, limit, "U,V")

    def parse(text: str) -> ImagePoint:
        u, v = pair(text)
        fraction = all("." in p for p in str(text).split(",")) and 0 <= u <= 1 and 0 <= v <= 1
        return ImagePoint(u, v, fraction)
    parse.__name__ = "point"
    return parse


def to_pixels(point: tuple[float, float], width: int, height: int) -> tuple[float, float]:
    """``point`` (an :class:`ImagePoint`, or a plain pair: pixels) as a pixel column and row, the
    ``--at`` of ``phyir.insert.views.place_object`` (whose pixel centres are at +0.5): a fraction
    ``f`` of the width is at ``f * width`` exactly, the seam's two sides (0 and 1) the same column."""
    u, v = point
    if not getattr(point, "fraction", False):
        return u, v
    return (u * width - 0.5) % width, min(max(v * height - 0.5, 0.0), height - 0.5)


def size(lo: int, hi: int, *, order: str = "WxH", max_pixels: int | None = None,
         multiple: int = 1) -> Callable[[str], tuple[int, int]]:
    """``AxB`` (``order`` names the two: ``WxH`` or ``HxW``): integers in [lo, hi], multiples of
    ``multiple``, at most ``max_pixels`` in all (the documented memory limit of the command)."""
    def parse(text: str) -> tuple[int, int]:
        parts = str(text).lower().split("x")
        try:
            a, b = (int(p) for p in parts)
        except ValueError:
            example = "512x256" if order == "WxH" else "256x512"
            raise argparse.ArgumentTypeError(f"expected {order} (e.g. {example}), got {text!r}") from None
        if not (lo <= a <= hi and lo <= b <= hi):
            raise argparse.ArgumentTypeError(f"expected {lo}..{hi} pixels per side, got {text!r}")
        if a % multiple or b % multiple:
            raise argparse.ArgumentTypeError(f"expected sides that are multiples of {multiple}, got {text!r}")
        if max_pixels is not None and a * b > max_pixels:
            raise argparse.ArgumentTypeError(f"{text} is {a * b:,} pixels, more than the limit of "
                                             f"{max_pixels:,}")
        return a, b
    parse.__name__ = "size"
    return parse


# any finite number / integer: for options whose range the library checks (e.g. TrainConfig.check)
finite = number(-math.inf, math.inf)
integer = number(-math.inf, math.inf, integer=True)


def path(text: str) -> str:
    """A file or folder name: not empty (``-o ""`` would mean the current folder, or no file at all)."""
    if not str(text).strip():
        raise argparse.ArgumentTypeError(f"expected a file or folder name, got {text!r}")
    return text


def device(text: str) -> str:
    """A torch device the commands run on: ``cpu``, ``cuda`` or ``cuda:N`` (``torch.device("bogus")``
    was a RuntimeError traceback; ``meta`` has no data to compute with)."""
    import re

    t = str(text).strip().lower()
    if not re.fullmatch(r"cpu|cuda(:\d+)?", t):
        raise argparse.ArgumentTypeError(f"expected cpu, cuda or cuda:N, got {text!r}")
    return t
