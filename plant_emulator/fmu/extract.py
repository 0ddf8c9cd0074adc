"""Opening and extracting an FMU archive within bounds.

An FMU is a ZIP archive from wherever a user got it. Before anything is read
from it, its central directory is checked (:func:`check_archive`): it must be
a regular file, hold at most :data:`MAX_MEMBERS` members of at most
:data:`MAX_TOTAL_BYTES` together once extracted, no member may expand more
than :data:`MAX_RATIO` times (a "zip bomb": 1.5 MB of zeros that extract to
1.5 GB), its model description must be at most
:data:`MAX_DESCRIPTION_BYTES`, and no member may be a symlink, an absolute
path or a path leaving the extraction folder. Each refusal is one
:class:`ArchiveRefused` line (a :class:`~protocol.errors.ConfigError`, as the loader's other refusals) naming the FMU and the
member, before a byte is extracted.

:func:`extract_fmu` then writes the members itself (not ``extractall``):
each file created exclusively, without following links, in a fresh 0700
folder, and the bytes written counted against the sizes the directory
declared (a member that inflates past its declared size is refused and the
folder removed). The folder is named after the extracting process
(``ralf-fmu-<pid>-*``): the next extraction removes those of processes that
ended without removing theirs (a plant that crashed in its FMU).
"""

from __future__ import annotations

import os
import shutil
import stat
import sys
import tempfile
import zipfile
from pathlib import Path, PurePosixPath

from protocol.errors import ConfigError
from protocol.files import NotARegularFile, check_regular_file

__all__ = [
    "MAX_DESCRIPTION_BYTES",
    "MAX_MEMBERS",
    "MAX_RATIO",
    "MAX_TOTAL_BYTES",
    "ArchiveRefused",
    "check_archive",
    "extract_fmu",
    "remove_orphaned_extractions",
]

MAX_MEMBERS = 10_000
"""The most members an FMU may hold (a plant's FMU: a description, a binary or three, sources, documentation)."""
MAX_TOTAL_BYTES = 512 * 1024 * 1024
"""The most bytes an FMU may extract to (its binaries for every platform and resources included)."""
MAX_RATIO = 200
"""The most a member larger than :data:`RATIO_FLOOR_BYTES` may expand (compiled code and text: 2–20 times)."""
RATIO_FLOOR_BYTES = 1024 * 1024
"""Members up to this size are not held to :data:`MAX_RATIO` (a small all-zero resource compresses well too)."""
MAX_DESCRIPTION_BYTES = 64 * 1024 * 1024
"""The largest ``modelDescription.xml`` (FMPy reads it into memory)."""
CHUNK_BYTES = 1024 * 1024


class ArchiveRefused(ConfigError):
    """An FMU archive the loader will not open or extract (one line naming the FMU and the member)."""


def _refuse(path: Path, why: str) -> ArchiveRefused:
    return ArchiveRefused(f"{path}: {why}")


def _unsafe_name(name: str) -> str | None:
    """Why a member's name cannot be extracted under a folder (None: it can)."""
    if "\\" in name or ":" in name:
        return "has a backslash or a drive letter"
    pure = PurePosixPath(name)
    if pure.is_absolute():
        return "is an absolute path"
    if ".." in pure.parts:
        return "leaves the extraction folder (..)"
    if not pure.parts or "\0" in name:
        return "has no usable name"
    return None


def check_archive(path: str | Path) -> list[zipfile.ZipInfo]:
    """The members of the FMU at ``path`` once every limit holds; else :class:`ArchiveRefused`."""
    p = Path(path)
    if not os.path.lexists(p):
        raise _refuse(p, "no such FMU file")
    try:
        check_regular_file(p, max_bytes=sys.maxsize)
    except NotARegularFile as exc:
        raise ArchiveRefused(f"FMU {exc}") from None
    try:
        with zipfile.ZipFile(p) as zf:
            members = zf.infolist()
    except zipfile.BadZipFile:
        raise _refuse(p, "not an FMU (not a ZIP archive)") from None
    except OSError as exc:
        raise _refuse(p, f"cannot be read ({exc.strerror or exc})") from None
    if len(members) > MAX_MEMBERS:
        raise _refuse(p, f"holds {len(members)} members, more than the {MAX_MEMBERS} an FMU may have")
    total = 0
    names: set[str] = set()
    for info in members:
        why = _unsafe_name(info.filename)
        if why:
            raise _refuse(p, f"member {info.filename!r} {why}")
        mode = info.external_attr >> 16
        if info.create_system == 3 and stat.S_ISLNK(mode):
            raise _refuse(p, f"member {info.filename!r} is a symlink (an FMU's files are regular files)")
        key = info.filename.rstrip("/")
        if key in names:
            raise _refuse(p, f"member {info.filename!r} appears twice")
        names.add(key)
        total += info.file_size
        if total > MAX_TOTAL_BYTES:
            raise _refuse(
                p, f"extracts to more than {MAX_TOTAL_BYTES // (1024 * 1024)} MiB (member {info.filename!r}: {info.file_size} bytes); refused before extracting"
            )
        if info.file_size > RATIO_FLOOR_BYTES and info.file_size > MAX_RATIO * max(1, info.compress_size):
            raise _refuse(
                p,
                f"member {info.filename!r} expands {info.file_size / max(1, info.compress_size):.0f} times "
                f"({info.compress_size} to {info.file_size} bytes), more than {MAX_RATIO}: refused before extracting",
            )
        if info.filename == "modelDescription.xml" and info.file_size > MAX_DESCRIPTION_BYTES:
            raise _refuse(p, f"its modelDescription.xml is {info.file_size} bytes, more than {MAX_DESCRIPTION_BYTES}")
    return members


def extract_fmu(path: str | Path) -> str:
    """Extract the FMU at ``path`` (checked by :func:`check_archive`) into a fresh
    0700 folder; its path. The caller removes the folder when done with it."""
    p = Path(path)
    members = check_archive(p)
    remove_orphaned_extractions()
    root = Path(tempfile.mkdtemp(prefix=f"ralf-fmu-{os.getpid()}-"))
    try:
        with zipfile.ZipFile(p) as zf:
            for info in members:
                target = root.joinpath(*PurePosixPath(info.filename).parts)
                if info.is_dir():
                    target.mkdir(parents=True, exist_ok=True, mode=0o700)
                    continue
                target.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
                _write_member(p, zf, info, target)
    except BaseException:
        shutil.rmtree(root, ignore_errors=True)
        raise
    return str(root)


def remove_orphaned_extractions() -> list[Path]:
    """Remove the extraction folders (``ralf-fmu-<pid>-*``) of this user's
    processes that have ended without removing theirs (a plant killed by a
    signal, a crash inside its FMU); returns them."""
    removed = []
    for folder in Path(tempfile.gettempdir()).glob("ralf-fmu-*-*"):
        pid_text = folder.name.split("-")[2]
        try:
            st = os.lstat(folder)
        except OSError:
            continue
        if not pid_text.isdigit() or not stat.S_ISDIR(st.st_mode) or st.st_uid != os.getuid():
            continue
        try:
            os.kill(int(pid_text), 0)
            continue  # still running (or a reused pid: left alone)
        except ProcessLookupError:
            pass
        except PermissionError:
            continue
        shutil.rmtree(folder, ignore_errors=True)
        removed.append(folder)
    return removed


def _write_member(path: Path, zf: zipfile.ZipFile, info: zipfile.ZipInfo, target: Path) -> None:
    mode = 0o700 if (info.external_attr >> 16) & 0o111 else 0o600
    fd = os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, mode)
    written = 0
    try:
        with zf.open(info) as src, os.fdopen(fd, "wb", closefd=False) as out:
            while chunk := src.read(CHUNK_BYTES):
                written += len(chunk)
                if written > info.file_size:
                    raise _refuse(path, f"member {info.filename!r} inflates past the {info.file_size} bytes its directory declares")
                out.write(chunk)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError) as exc:
        raise _refuse(path, f"member {info.filename!r} cannot be extracted ({' '.join(str(exc).split())})") from None
    finally:
        os.close(fd)
