"""Argument types and checks for command-line scripts built on argparse (the benchmarks in
``benchmarks/`` use them): every mistake is refused before any work starts, as argparse
refuses its own (one ``PROG: error: ...`` line, exit status 2).

    from latent_sindy.script_args import check_output_file, positive_int, seed_range

    p.add_argument("--seeds", nargs="+", type=seed_range, default=[[0, 1, 2]])
    p.add_argument("--workers", type=positive_int, default=2)
    args = p.parse_args(argv)
    check_output_file(p, args.json, "--json")
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

from latent_sindy.errors import MAX_SEED, UserError

__all__ = ["check_output_file", "parse_with_smoke", "positive_float", "positive_int",
           "seed_range"]


def seed_range(text: str) -> list[int]:
    """Seeds from ``3``, ``0..7`` (both ends included) or ``0,3,5``: each an integer in
    0..MAX_SEED, a range that holds at least one."""
    seeds: list[int] = []
    for part in text.split(","):
        lo, dots, hi = part.partition("..")
        try:
            a, b = int(lo), int(hi) if dots else int(lo)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"{text!r}: give seeds as integers, e.g. 0 1 2, 0..7 or 0,3,5") from None
        if not (0 <= a <= MAX_SEED and 0 <= b <= MAX_SEED):
            raise argparse.ArgumentTypeError(f"{text!r}: seeds are integers from 0 to "
                                             f"{MAX_SEED}")
        if b < a:
            raise argparse.ArgumentTypeError(f"{text!r}: the range {a}..{b} holds no seed; "
                                             f"write it low..high, e.g. {b}..{a}")
        seeds += range(a, b + 1)
    return seeds


def _number(text: str, kind: type, what: str) -> int | float:
    """``text`` read as ``kind``; argparse's error naming it as not ``what`` otherwise."""
    try:
        return kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None


def positive_int(text: str) -> int:
    value = _number(text, int, "an integer")
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value}: use 1 or more")
    return value


def positive_float(text: str) -> float:
    value = _number(text, float, "a number")
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text}: use a finite number > 0")
    return value


def check_output_file(parser: argparse.ArgumentParser, path: str | os.PathLike | None,
                      flag: str) -> None:
    """parser.error unless ``path`` (None: no output) can be written as a file: not a
    folder, in a folder that exists and lets us write, and writable where it exists.
    Nothing is created."""
    if path is None:
        return
    path = Path(path)
    folder = path.parent
    if path.is_dir():
        parser.error(f"{flag} {path} is a folder: give a file name")
    if not folder.is_dir():
        parser.error(f"{flag} {path}: {folder} is not an existing folder")
    if not os.access(folder, os.W_OK | os.X_OK) or (path.exists()
                                                     and not os.access(path, os.W_OK)):
        parser.error(f"{flag} {path}: cannot write there (permission denied); choose "
                     "another path")


def parse_with_smoke(parser: argparse.ArgumentParser, argv: list[str] | None,
                     smoke: dict[str, object]) -> argparse.Namespace:
    """``parser.parse_args(argv)`` with a ``--smoke`` flag added: with it, ``smoke``'s values
    (by destination, e.g. ``{"seeds": [[0]], "epochs": 1}``) become the defaults, so a smoke
    run is tiny yet still runs the real code path; a flag given on the line still wins."""
    for key in smoke:
        if not any(a.dest == key for a in parser._actions):
            raise UserError(f"parse_with_smoke: {key!r} is no option of {parser.prog}")
    parser.add_argument("--smoke", action="store_true",
                        help="tiny sizes that run in seconds (the tests run it): the real "
                             "code path, figures that mean nothing")
    args = parser.parse_args(argv)
    if args.smoke:
        parser.set_defaults(**smoke)
        args = parser.parse_args(argv)
    return args
