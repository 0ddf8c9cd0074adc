"""Files a rig keeps in a folder other users can write to (``TMPDIR``).

A name in a shared folder may already be taken by another user's symlink,
FIFO or folder. So the rig keeps such files in a private runtime folder:
``$XDG_RUNTIME_DIR`` when it is a folder of this user that nobody else may
enter, else ``TMPDIR/ralf-hil-<uid>``, created 0700 and checked (a folder,
not a link, owned by this user, closed to group and others) every time it is
used. Each file in it is opened with ``O_NOFOLLOW`` and checked on the open
descriptor to be a regular file of this user before anything is written.
Anything else is one :class:`UnsafePath` line naming the path and what it is;
nothing behind it is touched.

:class:`RunLock` is a host's lock of one rig id (``ralf-hil up``): an
exclusive ``flock`` on ``<runtime>/ralf-hil-<rig>.lock``, removed when the
run ends.

A run's credentials folder (:func:`run_folder`) holds a ``launcher`` file
naming the process that made it; :func:`remove_stale_run_folders` removes the
folders whose process is gone (a launcher ended by SIGKILL never removed
them), and :func:`remove_when_gone` (``python -m service_kit.private_files``)
removes one the moment its launcher ends.
"""

from __future__ import annotations

import errno
import os
import select
import shutil
import stat
import subprocess
import sys
import tempfile
from pathlib import Path

__all__ = [
    "LockHeld",
    "RunLock",
    "UnsafePath",
    "keep",
    "open_private_file",
    "remove_stale_run_folders",
    "remove_when_gone",
    "run_folder",
    "runtime_dir",
    "start_remover",
]


class UnsafePath(OSError):
    """A path in a shared folder that is not what the rig would have made there (a symlink, FIFO, folder, another user's file)."""


class LockHeld(OSError):
    """The rig's lock is held by another process (its text names the holder)."""


def _kind(mode: int) -> str:
    for test, name in (
        (stat.S_ISLNK, "a symlink"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISREG, "a regular file"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def _what_is(path: Path) -> str:
    try:
        st = os.lstat(path)
    except OSError as exc:
        return exc.strerror or str(exc)
    kind = _kind(st.st_mode)
    return f"{kind} of uid {st.st_uid}" if st.st_uid != os.getuid() else kind


def _private_folder(path: Path) -> bool:
    try:
        st = os.lstat(path)
    except OSError:
        return False
    return stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid() and not st.st_mode & 0o077


def runtime_dir() -> Path:
    """This user's private runtime folder: ``$XDG_RUNTIME_DIR`` when it is
    private to this user, else ``TMPDIR/ralf-hil-<uid>`` (made 0700 if absent;
    a link, a file, or a folder of another user or open to others there is an
    :class:`UnsafePath`)."""
    xdg = os.environ.get("XDG_RUNTIME_DIR", "")
    if xdg and os.path.isabs(xdg) and _private_folder(Path(xdg)):
        return Path(xdg)
    path = Path(tempfile.gettempdir()) / f"ralf-hil-{os.getuid()}"
    try:
        os.mkdir(path, 0o700)
    except FileExistsError:
        pass
    except OSError as exc:
        raise UnsafePath(f"{path}: cannot make the private runtime folder ({exc.strerror or exc})") from None
    try:
        st = os.lstat(path)
    except OSError as exc:
        raise UnsafePath(f"{path}: {exc.strerror or exc}") from None
    if not stat.S_ISDIR(st.st_mode):
        raise UnsafePath(f"{path} is {_kind(st.st_mode)}, not this user's private runtime folder")
    if st.st_uid != os.getuid():
        raise UnsafePath(f"{path} belongs to uid {st.st_uid}, not this user ({os.getuid()}): not a private runtime folder")
    if st.st_mode & 0o077:
        raise UnsafePath(f"{path} is open to other users (mode {stat.S_IMODE(st.st_mode):o}): not a private runtime folder")
    return path


def open_private_file(path: str | Path, flags: int = os.O_RDWR) -> int:
    """A descriptor of ``path``, created 0600 if absent, never through a link:
    it must be a regular file of this user (checked on the descriptor; a FIFO
    does not block the open). Else :class:`UnsafePath` saying what is there."""
    p = Path(path)
    try:
        fd = os.open(p, flags | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, 0o600)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.EISDIR, errno.ENXIO, errno.EACCES, errno.EPERM, errno.ENOTDIR):
            raise UnsafePath(f"{p} is {_what_is(p)}, not a regular file of this user; remove it") from None
        raise UnsafePath(f"{p}: {exc.strerror or exc}") from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode) or st.st_uid != os.getuid():
        os.close(fd)
        what = _kind(st.st_mode) if not stat.S_ISREG(st.st_mode) else f"a file of uid {st.st_uid}"
        raise UnsafePath(f"{p} is {what}, not a regular file of this user; remove it")
    os.set_blocking(fd, True)
    return fd


class RunLock:
    """The host's lock of one rig id, held while the object is open (:meth:`release` removes the file)."""

    def __init__(self, path: Path, fd: int) -> None:
        self.path = path
        self._fd: int | None = fd

    @classmethod
    def acquire(cls, rig_id: str, directory: str | Path | None = None) -> RunLock:
        """The lock of ``rig_id`` in ``directory`` (default: :func:`runtime_dir`);
        :class:`LockHeld` naming the holder, or :class:`UnsafePath`."""
        path = Path(directory) if directory is not None else runtime_dir()
        path = path / f"ralf-hil-{rig_id}.lock"
        import fcntl

        for _ in range(8):
            fd = open_private_file(path)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "another process"
                os.close(fd)
                raise LockHeld(holder) from None
            # The file still at the path? A holder that ended between our open and flock removed it.
            try:
                now, held = os.lstat(path), os.fstat(fd)
            except FileNotFoundError:
                os.close(fd)
                continue
            if (now.st_dev, now.st_ino) != (held.st_dev, held.st_ino):
                os.close(fd)
                continue
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"pid {os.getpid()}".encode(), 0)
            return cls(path, fd)
        raise LockHeld(f"{path} keeps being replaced")

    def release(self) -> None:
        """Remove the file, then let go of the lock (another run then makes a new file)."""
        if self._fd is None:
            return
        try:
            if os.path.samestat(os.lstat(self.path), os.fstat(self._fd)):
                self.path.unlink()
        except OSError:
            pass
        os.close(self._fd)
        self._fd = None

    close = release

    def __enter__(self) -> RunLock:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.release()


LAUNCHER_FILE = "launcher"
"""The file in a run folder naming the process it belongs to: ``<pid> <start time in clock ticks>``."""


def _start_ticks(pid: int) -> str | None:
    """The process's start time (``/proc/<pid>/stat`` field 22): a pid reused by
    another process has another; None when the process has ended (a zombie too)."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text.rsplit(")", 1)[1].split()
    return None if fields[0] in ("Z", "X") else fields[19]  # a zombie has ended: only its exit status is left


def run_folder(prefix: str, pid: int | None = None) -> Path:
    """A fresh 0700 folder for a run's private files (keys, certificates) in
    :func:`runtime_dir`, marked with the process it belongs to (default: this one)."""
    pid = os.getpid() if pid is None else pid
    path = Path(tempfile.mkdtemp(prefix=prefix, dir=runtime_dir()))
    fd = os.open(path / LAUNCHER_FILE, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
    with os.fdopen(fd, "w") as fh:
        fh.write(f"{pid} {_start_ticks(pid) or '-'}\n")
    return path


def keep(folder: Path) -> None:
    """Keep ``folder`` past its process (no longer removed as stale)."""
    (folder / LAUNCHER_FILE).unlink(missing_ok=True)


def _owner_gone(folder: Path) -> bool:
    try:
        pid_text, ticks = (folder / LAUNCHER_FILE).read_text().split()
        pid = int(pid_text)
    except (OSError, ValueError):
        return False  # kept, or not a run folder: not ours to remove
    now = _start_ticks(pid)
    return now is None or (ticks != "-" and now != ticks)


def remove_stale_run_folders(pattern: str = "ralf-*-access-*") -> list[Path]:
    """Remove the run folders in :func:`runtime_dir` whose process has ended; returns them."""
    removed = []
    base = runtime_dir()
    for folder in sorted(base.glob(pattern)):
        if _private_folder(folder) and _owner_gone(folder):
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    return removed


REMOVER_POLL_S = 1.0
"""How often the remover also checks that its folder is still there (removed at a normal end: it leaves too)."""


def remove_when_gone(pidfd: int, folder: Path, poll_s: float = REMOVER_POLL_S) -> None:
    """Wait until the process of ``pidfd`` ends (or ``folder`` is gone), then remove ``folder``."""
    while folder.is_dir():
        ready, _, _ = select.select([pidfd], [], [], poll_s)
        if ready:
            if not folder.is_symlink() and _owner_gone(folder):
                shutil.rmtree(folder, ignore_errors=True)
            return


def start_remover(folder: Path) -> None:
    """A process that removes ``folder`` when this one ends, however it ends
    (SIGKILL too). It holds a pidfd of this process (no pid to be reused),
    runs in a session of its own (a signal to this process's group leaves it)
    and is no child of this process: it forks once more and its parent ends
    here, so it is not among this process's children while the run goes on."""
    pidfd = os.pidfd_open(os.getpid())
    try:
        subprocess.run(
            [sys.executable, "-P", "-m", "service_kit.private_files", str(pidfd), str(folder)],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            start_new_session=True,
            pass_fds=(pidfd,),
            check=False,
            timeout=60,
        )
    finally:
        os.close(pidfd)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2 or not args[0].isdigit():
        print("usage: python -m service_kit.private_files PIDFD FOLDER   (removes FOLDER when the process of PIDFD ends)", file=sys.stderr)
        return 2
    if os.fork():  # the parent returns to the launcher at once; the child waits, re-parented
        return 0
    remove_when_gone(int(args[0]), Path(args[1]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
