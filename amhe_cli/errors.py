"""User-facing errors.

Everything a user can get wrong (a missing file, a log without a box pose, a
window longer than the log) raises :class:`AmheError` with a one-line message
naming what is wrong and what was expected. The CLI prints it as
``amhe: error: <message>`` and exits with status 2, without a traceback.
"""


class AmheError(Exception):
    """A problem with the user's input, reported as one line and exit code 2."""


def check_names(given, known, what: str) -> None:
    """Raise :class:`AmheError` naming the entries of ``given`` that are not in ``known``.

    Args:
        given: names a user supplied (config keys, settings, modes).
        known: the accepted names.
        what: what a name is, for the message, e.g. ``"planner setting"``.
    """
    bad = set(given) - set(known)
    if bad:
        raise AmheError(f"unknown {what} {', '.join(sorted(map(str, bad)))}: "
                        f"expected one of {', '.join(sorted(map(str, known)))}")
