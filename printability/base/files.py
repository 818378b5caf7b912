"""Atomic file writes: a reader never sees a half-written file.

:func:`replace_file` writes the new content into a file of the destination's folder that has
no name yet (Linux's ``O_TMPFILE``; elsewhere a ``.NAME.RANDOM.tmp`` removed on any
exception), gives it the mode and, where this process may, the owner of the file it replaces
(a new file: 0666 less the umask, as ``open`` makes it), and renames it over the
destination. A process killed while writing (even by SIGKILL) leaves the destination as it
was and, on Linux, nothing beside it.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import stat
import tempfile
from pathlib import Path

from printability.base.errors import PrintabilityOSError

__all__ = ["current_umask", "replace_file", "write_atomic"]


def current_umask() -> int:
    """The process's umask, read without changing it where the system says it
    (``/proc/self/status``); elsewhere set and put back at once."""
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _unnamed(directory: Path) -> int | None:
    """A file of ``directory`` with no name (``O_TMPFILE``), or None where there is none."""
    flag = getattr(os, "O_TMPFILE", 0)
    if not flag or not os.path.isdir("/proc/self/fd"):
        return None
    try:
        return os.open(directory, flag | os.O_WRONLY | getattr(os, "O_CLOEXEC", 0), 0o600)
    except OSError:  # a file system without O_TMPFILE (EOPNOTSUPP, EISDIR on old kernels)
        return None


def _match(fd: int, old: os.stat_result | None) -> None:
    """Give the open file ``fd`` the owner and mode of ``old`` (the file it will replace).

    The owner is kept where this process may set it (root; or the group, for a user in
    it); otherwise the file is the writer's, as any new file would be. The mode is set
    after the owner (a change of owner clears set-user-ID bits).
    """
    if old is None:
        os.fchmod(fd, 0o666 & ~current_umask())
        return
    mine = os.fstat(fd)
    if (old.st_uid, old.st_gid) != (mine.st_uid, mine.st_gid):
        try:
            os.fchown(fd, old.st_uid, old.st_gid)
        except OSError:
            with contextlib.suppress(OSError):
                os.fchown(fd, -1, old.st_gid)
    os.fchmod(fd, stat.S_IMODE(old.st_mode))


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


def replace_file(path: str | os.PathLike[str], data: bytes) -> None:
    """Replace (or create) ``path`` with ``data`` atomically, keeping its mode and owner.

    Parameters
    ----------
    path
        The destination; its folder must exist. A symbolic link is replaced by the file.
    data
        The new content.

    Raises
    ------
    OSError
        The folder cannot be written, the disk is full...; the destination is as it was
        and no temporary file is left.
    """
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    try:
        old: os.stat_result | None = path.stat()
    except FileNotFoundError:
        old = None
    if old is not None and not stat.S_ISREG(old.st_mode):
        old = None  # a device or a folder: no mode or owner to keep for a regular file
    tmp: Path | None = None
    fd = _unnamed(directory)
    unnamed = fd is not None
    try:
        if fd is None:
            fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=directory)
            tmp = Path(name)
        try:
            _write_all(fd, data)
            _match(fd, old)
            os.fsync(fd)
            if unnamed:
                # a name at the last moment, then the rename: only a kill between the two
                # (microseconds) could leave it
                tmp = _name(fd, directory, path.name)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        raise


def _name(fd: int, directory: Path, name: str) -> Path:
    """Give the unnamed file ``fd`` a new temporary name in ``directory``.

    ``linkat(..., AT_SYMLINK_FOLLOW)`` of ``/proc/self/fd/N``, the way ``open(2)`` documents
    for ``O_TMPFILE``; a directory descriptor is passed because Python calls plain
    ``link(2)`` (which links the /proc entry itself: EXDEV) when none is.
    """
    dfd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        while True:
            tmp = f".{name}.{secrets.token_hex(4)}.tmp"
            try:
                os.link(f"/proc/self/fd/{fd}", tmp, src_dir_fd=dfd, dst_dir_fd=dfd,
                        follow_symlinks=True)
                return directory / tmp
            except FileExistsError:
                continue
    finally:
        os.close(dfd)


def write_atomic(path: str | Path, data: bytes | str) -> None:
    """Write a file through :func:`replace_file`, creating its folder first.

    A reader never sees a half-written file; on failure the previous file (if any) is left
    untouched, and an existing file keeps its mode and owner.

    Raises
    ------
    PrintabilityOSError
        The file cannot be written (one paragraph naming it).
    """
    path = Path(path)
    raw = data.encode("utf-8") if isinstance(data, str) else data
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        replace_file(path, raw)
    except OSError as exc:
        raise PrintabilityOSError(f"{path}: cannot write ({exc.strerror or exc})") from None
