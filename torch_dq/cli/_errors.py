"""How the commands fail (private): the errors that end a command in one line on stderr and
exit status 2."""

from __future__ import annotations

import sys

__all__ = ["OptionError", "exit_on_error"]


class OptionError(ValueError):
    """Options that this data cannot satisfy (the message says what to pass instead).

    The command line ends with it in one line and exit status 2, as for a bad option.
    """


def exit_on_error(program: str, exc: BaseException) -> int:
    """Print ``exc`` as one line ``"{program}: error: ..."`` on stderr (its whitespace,
    newlines included, collapsed; an operating system's error as ``"{file}: {reason}"``, not
    Python's ``[Errno N]`` form); returns the exit status 2."""
    text = str(exc)
    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}"
    print(f"{program}: error: {' '.join(text.split())}", file=sys.stderr)
    return 2
