"""The one exception type for mistakes a user can fix (bad file, bad setting).

:class:`UserError` is a :class:`ValueError`, so library callers catch it as they would any
bad argument. Library code words its messages for Python users (settings by their field
names); the CLI prints the message as a single line and exits with status 2. Everything else
is a bug and keeps its traceback.
"""


class UserError(ValueError):
    """A problem with the user's input; the message names the file or value and the fix."""
