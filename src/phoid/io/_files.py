"""Opening only regular files: a named pipe or a device is refused before it is read."""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import BinaryIO

from phoid.io._format import fail

__all__ = ["FILE_KINDS", "not_regular", "open_regular"]


FILE_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a named pipe (FIFO)"),
              (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
              (stat.S_ISSOCK, "a socket"))


def not_regular(mode: int) -> str | None:
    """What a non-regular file is ("a named pipe (FIFO)", …); None for a regular file."""
    if stat.S_ISREG(mode):
        return None
    return next((name for test, name in FILE_KINDS if test(mode)), "not a regular file")


def open_regular(where: str, path: Path, what: str) -> tuple[BinaryIO, os.stat_result]:
    """Open a regular file for reading, refusing anything else before it is read.

    A named pipe would block the read forever and a device (``/dev/zero``) would never end:
    the file's type is checked (after symbolic links are resolved) before it is opened, and
    again on the open file (non-blocking open, so that a pipe swapped in meanwhile cannot
    block either).
    """
    try:
        kind = not_regular(os.stat(path).st_mode)
    except OSError as exc:
        fail(where, f"cannot read the {what}: {exc.strerror or exc}")
    if kind is not None:
        fail(where, f"the {what} is {kind}, not a regular file; phoid reads only regular "
                     "files")
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) \
        | getattr(os, "O_BINARY", 0)
    try:
        fd = os.open(path, flags)
    except OSError as exc:
        fail(where, f"cannot read the {what}: {exc.strerror or exc}")
    try:
        st = os.fstat(fd)
        kind = not_regular(st.st_mode)
        if kind is not None:
            fail(where, f"the {what} is {kind}, not a regular file; phoid reads only "
                         "regular files")
        return os.fdopen(fd, "rb"), st
    except BaseException:
        os.close(fd)
        raise
