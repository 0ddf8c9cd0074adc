"""Files a rig keeps where other users may write (service_kit/private_files.py):
the rig lock and the run's credentials folder. A planted symlink, FIFO or
folder is one line and exit 2, and nothing behind it is touched; the lock
file is removed at the end of the run; a run's keys do not outlive a launcher
killed by SIGKILL."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from service_kit.private_files import RunLock, UnsafePath, keep, remove_stale_run_folders, run_folder, runtime_dir
from workbench.progress import messages

LOCK_CODE = "import sys; from workbench.cli import acquire_rig_lock; acquire_rig_lock('planted', sys.argv[1] if len(sys.argv) > 1 else None)"


def _take_lock(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", LOCK_CODE, *args], capture_output=True, text=True, timeout=60, check=False, env=env)


def _plant(kind: str, path: Path, victim: Path) -> None:
    if kind == "symlink":
        path.symlink_to(victim)
    elif kind == "dangling symlink":
        path.symlink_to(victim.with_name("absent"))
    elif kind == "FIFO":
        os.mkfifo(path)
    else:
        path.mkdir()


@pytest.mark.parametrize("kind", ["symlink", "dangling symlink", "FIFO", "folder"])
def test_a_planted_lock_path_is_one_line_and_exit_2(tmp_path: Path, kind: str) -> None:
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    lock = tmp_path / "ralf-hil-planted.lock"
    _plant(kind, lock, victim)
    proc = _take_lock(str(tmp_path))
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and len(messages(proc.stderr)) == 1, proc.stderr
    assert str(lock) in proc.stderr and kind.split()[-1].lower() in proc.stderr.lower(), proc.stderr
    assert victim.read_text() == "precious\n"  # the file behind the link is untouched
    assert not victim.with_name("absent").exists()  # nothing made through a dangling link
    assert os.path.lexists(lock) and not stat.S_ISREG(os.lstat(lock).st_mode)  # what was planted stays as it was


@pytest.mark.parametrize("kind", ["symlink", "FIFO", "folder open to others"])
def test_a_planted_runtime_folder_is_one_line_and_exit_2(tmp_path: Path, kind: str) -> None:
    shared, victim = tmp_path / "shared", tmp_path / "victim"
    shared.mkdir()
    victim.mkdir()
    planted = shared / f"ralf-hil-{os.getuid()}"
    if kind == "symlink":
        planted.symlink_to(victim)
    elif kind == "FIFO":
        os.mkfifo(planted)
    else:
        planted.mkdir(mode=0o777)
        planted.chmod(0o777)
    env = {k: v for k, v in os.environ.items() if k != "XDG_RUNTIME_DIR"} | {"TMPDIR": str(shared)}
    proc = _take_lock(env=env)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr and len(messages(proc.stderr)) == 1, proc.stderr
    assert str(planted) in proc.stderr
    assert not any(victim.iterdir())  # nothing made through the link
    if kind == "folder open to others":
        assert not any(planted.iterdir())


def test_the_lock_lives_in_the_private_runtime_folder_and_is_removed_at_the_end(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("XDG_RUNTIME_DIR", raising=False)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr("tempfile.tempdir", None)
    folder = runtime_dir()
    assert folder == tmp_path / f"ralf-hil-{os.getuid()}" and stat.S_IMODE(folder.stat().st_mode) == 0o700
    with RunLock.acquire("tidy") as lock:
        assert lock.path.parent == folder and lock.path.read_text() == f"pid {os.getpid()}"
        assert stat.S_IMODE(lock.path.stat().st_mode) == 0o600
    assert not lock.path.exists()
    with RunLock.acquire("tidy"):  # a new file for the next run
        pass


def test_an_xdg_runtime_folder_of_this_user_is_used(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    xdg = tmp_path / "run-user"
    xdg.mkdir(mode=0o700)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(xdg))
    assert runtime_dir() == xdg
    xdg.chmod(0o755)  # open to others: not private, the per-user folder under TMPDIR instead
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    monkeypatch.setattr("tempfile.tempdir", None)
    assert runtime_dir() == tmp_path / f"ralf-hil-{os.getuid()}"


def test_a_lock_file_of_another_user_is_refused(tmp_path: Path) -> None:
    if os.getuid() != 0:
        pytest.skip("making a file of another user needs root")
    lock = tmp_path / "ralf-hil-foreign.lock"
    lock.write_text("theirs")
    os.chown(lock, 65534, 65534)
    with pytest.raises(UnsafePath, match="uid 65534"):
        RunLock.acquire("foreign", tmp_path)
    assert lock.read_text() == "theirs"


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_stale_run_folders_of_ended_launchers_are_removed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    tmp_path.chmod(0o700)
    ended = run_folder("ralf-a-access-", pid=_dead_pid())
    (ended / "controller.key").write_text("secret")
    mine = run_folder("ralf-b-access-")
    kept = run_folder("ralf-c-access-", pid=_dead_pid())
    keep(kept)  # --keep-credentials: the user's to remove
    assert remove_stale_run_folders() == [ended]
    assert not ended.exists() and mine.is_dir() and kept.is_dir()
    assert stat.S_IMODE(mine.stat().st_mode) == 0o700


LAUNCHER = """
import sys, time
from workbench.cli import private_run_dir
from service_kit.private_files import start_remover
folder = private_run_dir("ralf-killed-access-")
(folder / "controller.key").write_text("secret")
start_remover(folder)
print(folder, flush=True)
time.sleep(120)
"""


@pytest.mark.timeout(120)
def test_keys_do_not_outlive_a_launcher_killed_by_sigkill(tmp_path: Path) -> None:
    tmp_path.chmod(0o700)
    env = {**os.environ, "XDG_RUNTIME_DIR": str(tmp_path)}
    proc = subprocess.Popen([sys.executable, "-c", LAUNCHER], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout is not None
        folder = Path(proc.stdout.readline().strip())
        assert (folder / "controller.key").read_text() == "secret"
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        for _ in range(300):  # the remover wakes when the launcher ends; bounded wait for it
            if not folder.exists():
                break
            time.sleep(0.1)
        assert not folder.exists()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.rig
@pytest.mark.timeout(300)
def test_keys_do_not_outlive_ralf_hil_up_killed_by_sigkill(tmp_path: Path) -> None:
    """A real ``ralf-hil up`` (its services running) killed by SIGKILL: its credentials folder goes with it."""
    rig_id = f"kill-{os.getpid()}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "workbench", "up", "--duration", "120", "--rig-id", rig_id, "--log-dir", str(tmp_path / "logs")],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,  # the header (stdout) names the credentials, the ready line is on stderr
        text=True,
        start_new_session=True,
    )
    try:
        assert proc.stdout is not None
        seen = ""
        while "all services ready" not in seen:
            line = proc.stdout.readline()
            assert line, f"up ended before the rig was ready: {seen}"
            seen += line
        tool_env = Path(" ".join(seen.split()).split("tools' credentials in ", 1)[1].split()[0])
        folder = tool_env.parent
        assert {"ca.pem", "controller.key", "dsp.key"} <= {p.name for p in folder.iterdir()}
        assert folder.parent == runtime_dir() and stat.S_IMODE(folder.stat().st_mode) == 0o700
        proc.send_signal(signal.SIGKILL)  # the launcher only: its services end with it (parent-death signal)
        proc.wait()
        for _ in range(300):
            if not folder.exists():
                break
            time.sleep(0.1)
        assert not folder.exists()
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
