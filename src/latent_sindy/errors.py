"""The one exception type for mistakes a user can fix (bad file, bad setting).

:class:`UserError` is a :class:`ValueError`, so library callers catch it as they would any
bad argument. The CLI prints its message as a single line and exits with status 2; everything
else is a bug and keeps its traceback.

Settings are validated while the CLI's parser builds them, and that parser reports every
ValueError a constructor raises in a box of its own. Inside :func:`carried_through_parsers`
a UserError is raised as a :class:`CarriedUserError` instead (not a ValueError), so it reaches
the CLI, which prints it like any other.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

__all__ = ["MAX_SEED", "CarriedUserError", "UserError", "carried_through_parsers",
           "check_seed"]

_carrying = False


class CarriedUserError(Exception):
    """A UserError raised while the CLI parses its settings (see the module docstring)."""


class UserError(ValueError):
    """A problem with the user's input; the message names the file or value and the fix."""

    def __new__(cls, *args, **kwargs):
        if _carrying:
            return CarriedUserError(*args)
        return super().__new__(cls, *args, **kwargs)


#: The largest seed any command or setting takes: numpy's legacy range, so that every seed
#: derived from one (seed × 100 003 + index, seed × 1000 + episode) still fits the 64-bit
#: integers that torch and numpy seed with.
MAX_SEED = 2**32 - 1


def check_seed(seed: object, flag: str) -> None:
    """UserError unless ``seed`` is an integer in 0..:data:`MAX_SEED` (``flag`` names it)."""
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise UserError(f"{flag} {seed}: seeds are integers from 0 to {MAX_SEED}")


@contextlib.contextmanager
def carried_through_parsers() -> Iterator[None]:
    """UserErrors raised inside are CarriedUserErrors (for the CLI's parsing only)."""
    global _carrying
    _carrying = True
    try:
        yield
    finally:
        _carrying = False
