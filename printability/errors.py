"""Exception hierarchy of printability.

Every error a user can cause derives from :class:`PrintabilityError`; each
subclass also derives from the matching built-in (``ValueError``, ``OSError``,
``MemoryError``) so callers that catch the built-ins keep working. The CLI
turns any ``PrintabilityError`` into a one-paragraph message on stderr and
exit code 1; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

__all__ = [
    "FileFormatError",
    "InputError",
    "NozzleTooLargeError",
    "PrintabilityError",
    "PrintabilityOSError",
    "PrinterError",
    "ResourceError",
    "StoppedError",
    "UnknownOptionError",
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
