"""The one exception type for mistakes a user can fix (bad file, bad setting).

The CLI prints its message as a single line and exits with status 2; everything else is a
bug and keeps its traceback.
"""


class UserError(Exception):
    """A problem with the user's input; the message names the file or value and the fix."""


def reject_unknown_fields(cls: type, d: object, what: str) -> None:
    """UserError if mapping `d` has keys that are not fields of dataclass `cls`."""
    import dataclasses

    unknown = set(d) - {f.name for f in dataclasses.fields(cls)}
    if unknown:
        raise UserError(f"unknown {what} settings {sorted(unknown)}")
