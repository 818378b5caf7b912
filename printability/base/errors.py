"""Exception hierarchy of printability.

Every error a user can cause derives from :class:`PrintabilityError`; each
subclass also derives from the matching built-in (``ValueError``, ``OSError``,
``MemoryError``) so callers that catch the built-ins keep working. The CLI
turns any ``PrintabilityError`` into a one-paragraph message on stderr and
exit code 1; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

__all__ = [
    "EXCERPT_LENGTH",
    "FileFormatError",
    "InputError",
    "NozzleTooLargeError",
    "PrintabilityError",
    "PrintabilityOSError",
    "PrinterError",
    "ResourceError",
    "StoppedError",
    "UnknownOptionError",
    "excerpt",
]


class PrintabilityError(Exception):
    """Root of every error printability raises on purpose."""


class InputError(PrintabilityError, ValueError):
    """A value given by the user is not acceptable (wrong range, empty region...)."""


class UnknownOptionError(InputError):
    """A string option is not in its registry; the message lists the valid choices."""


class NozzleTooLargeError(InputError):
    """The nozzle cannot fit inside the region at any configuration: nothing prints."""


class FileFormatError(InputError):
    """A file could not be understood.

    Parameters
    ----------
    path
        The file concerned.
    message
        What was expected and what was found.
    line
        1-based line number, when the format has lines.
    element
        Name of the element (XML tag, JSON key, TOML table...) when it has one.
    """

    def __init__(
        self,
        path: object,
        message: str,
        *,
        line: int | None = None,
        element: str | None = None,
    ) -> None:
        self.path = str(path)
        self.line = line
        self.element = element
        where = self.path
        if line is not None:
            where += f", line {line}"
        if element is not None:
            where += f", {element}"
        super().__init__(f"{where}: {message}")


class PrintabilityOSError(PrintabilityError, OSError):
    """A file, port or device could not be opened, read or written."""


class ResourceError(PrintabilityError, MemoryError):
    """The work asked for would need more memory (or time) than allowed.

    Raised *before* the allocation, from an estimate, so nothing swaps.
    """


class PrinterError(PrintabilityError, RuntimeError):
    """The printer (or the link to it) reported an error or stopped answering."""


class StoppedError(PrintabilityError, InterruptedError):
    """The process was asked to stop (SIGTERM, SIGHUP, SIGQUIT) while it worked; what it was
    writing is left as it was."""



#: Characters of user input an error message quotes at most (see :func:`excerpt`).
EXCERPT_LENGTH = 60


def excerpt(value: str | bytes | bytearray, limit: int = EXCERPT_LENGTH) -> str:
    r"""A short quoted piece of user input for an error message.

    At most ``limit`` characters (bytes for ``bytes``) of ``value`` are shown
    between quotes, then ``…`` when there was more. What a terminal would not
    show as itself is escaped: control and format characters as ``\x01``,
    ``\t``, ``\u202e``; bytes that are not UTF-8 as ``\xff``. The cost does not
    depend on the length of ``value``: a 10 MB line quoted whole makes a 10 MB
    message (which the terminal wrapping then takes minutes over), and quoting
    a whole line of the wrong file repeats its contents.

    Parameters
    ----------
    value
        The text or bytes to quote.
    limit
        Most characters (bytes) of ``value`` shown.

    Returns
    -------
    str
        ``'G1 X1 Y2'``, or ``'EXCLUDE_OBJECT_DEFINE NAME=a POLYGON=[[0,0],'…`` when cut.

    Examples
    --------
    >>> print(excerpt("G1 X\x01"))
    'G1 X\x01'
    >>> print(excerpt("x" * 100, 5))
    'xxxxx'…
    >>> print(excerpt(b"M117 \xff"))
    'M117 \xff'
    """
    head = value[:limit]
    if isinstance(head, (bytes, bytearray)):
        head = bytes(head).decode("utf-8", "backslashreplace")
    shown = "".join(c if c.isprintable() else repr(c)[1:-1] for c in head)
    return f"'{shown}'" + ("…" if len(value) > limit else "")
