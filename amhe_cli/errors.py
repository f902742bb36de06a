"""User-facing errors.

Everything a user can get wrong (a missing file, a log without a box pose, a
window longer than the log) raises :class:`AmheError` with a one-line message
naming what is wrong and what was expected. The CLI prints it as
``amhe: error: <message>`` and exits with status 2, without a traceback.
"""


class AmheError(Exception):
    """A problem with the user's input, reported as one line and exit code 2."""
