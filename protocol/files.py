"""Reading a file a setting names, without letting it stall a start: the path
must be a regular file (a FIFO would block ``open`` until a writer comes, a
character device would never end), it is opened with ``O_NONBLOCK`` and its
type checked again on the open descriptor (a FIFO swapped in after the first
check does not block either), and it is read up to a size limit."""

from __future__ import annotations

import os
import stat
from pathlib import Path

__all__ = ["MAX_BYTES", "NotARegularFile", "check_regular_file", "read_regular_text"]

MAX_BYTES = 16 * 1024 * 1024
"""The largest file a setting may name (way-points, scenarios: kilobytes)."""


class NotARegularFile(OSError):
    """The path names something other than a readable regular file of sane size."""


def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "a directory" if stat.S_ISDIR(mode) else "not a regular file"


def check_regular_file(path: str | Path, max_bytes: int = MAX_BYTES) -> Path:
    """``path`` if it names an existing regular file of at most ``max_bytes``; else :class:`NotARegularFile` saying what it is."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError as exc:
        raise NotARegularFile(f"{p}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise NotARegularFile(f"{p} is {_kind(st.st_mode)}, not a regular file")
    if st.st_size > max_bytes:
        raise NotARegularFile(f"{p} is {st.st_size} bytes, more than the {max_bytes} a setting's file may have")
    return p


def read_regular_text(path: str | Path, max_bytes: int = MAX_BYTES) -> str:
    """The text (UTF-8) of a regular file, never blocking on what the path turns out to be."""
    p = check_regular_file(path, max_bytes)
    fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise NotARegularFile(f"{p} is {_kind(st.st_mode)}, not a regular file")
        data = os.read(fd, max_bytes + 1)
        chunks = [data]
        while data and sum(map(len, chunks)) <= max_bytes:
            data = os.read(fd, max_bytes + 1)
            chunks.append(data)
    finally:
        os.close(fd)
    raw = b"".join(chunks)
    if len(raw) > max_bytes:
        raise NotARegularFile(f"{p} grew past {max_bytes} bytes while read")
    return raw.decode("utf-8")
