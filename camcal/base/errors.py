"""The one exception type camcal raises for a user's bad input."""

__all__ = ["CamcalError"]


class CamcalError(Exception):
    """Bad input named in one line: the CLI prints it and exits with code 2.

    Raised for a user's mistake (missing file, malformed JSON, too few points,
    degenerate geometry...), never for a bug in camcal. It is deliberately not
    a ``ValueError``: an ``except ValueError`` around numerical code must not
    swallow a user's error, and a ``ValueError`` escaping the library is an
    internal error (exit code 1), not bad input.
    """
