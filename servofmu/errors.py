"""The one exception type for errors a user can cause (bad file, option, variable name, data).

The CLI reports a UserError as one line on stderr and exits with status 2; anything else is a bug.
"""


class UserError(Exception):
    """An error caused by input: the message names the culprit and fits on one line."""
