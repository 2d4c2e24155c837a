"""The one exception type for mistakes a user can fix (bad file, bad setting).

The CLI prints its message as a single line and exits with status 2; everything else is a
bug and keeps its traceback.
"""


class UserError(Exception):
    """A problem with the user's input; the message names the file or value and the fix."""
