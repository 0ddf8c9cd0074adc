"""What a run leaves behind can be trusted: each service's record is its own
file (set once for the whole rig, as a user would), no password is in any
file or output of a run, the run's credentials live in an owner-only folder
removed at exit, and nothing outlives a launcher killed by SIGKILL; the
recording it was writing reads up to the cut."""

from __future__ import annotations

import json
import os
import re
import signal
import stat
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from controller.record import load_record

UP = [sys.executable, "-m", "workbench", "up"]


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RALF_")}
    env["COLUMNS"] = "400"  # rich wraps its lines at the terminal's width
    env.update(extra)
    return env


def _rig() -> str:
    return f"art-{uuid.uuid4().hex[:6]}"


def _run(args: list[str], env: dict[str, str] | None = None, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    return subprocess.run(args, capture_output=True, text=True, timeout=timeout, env=env or _env(), check=False)


def _access_dir(stdout: str) -> Path:
    match = re.search(r"tools'\s+credentials\s+in\s+(\S+)", stdout)
    assert match, stdout
    return Path(match.group(1)).parent


def test_the_retired_shared_record_setting_is_refused_naming_the_new_ones(tmp_path: Path) -> None:
    proc = _run([*UP, "--clock", "lockstep", "--rig-id", _rig()], env=_env(RALF_RECORD=str(tmp_path / "rec")), timeout=60)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    said = proc.stdout + proc.stderr
    assert "RALF_RUN_RECORD" in said and "RALF_TRUTH_RECORD" in said and "Traceback" not in said
    proc = _run([*UP, "--clock", "lockstep", "--rig-id", _rig(), "--set", f"record={tmp_path / 'rec'}"], timeout=60)
    assert proc.returncode == 2 and "RALF_RUN_RECORD" in proc.stderr and "Traceback" not in proc.stderr
    service = _run([sys.executable, "-m", "controller", "--set", f"record={tmp_path / 'rec'}"], timeout=60)
    assert service.returncode == 2 and "RALF_TRUTH_RECORD" in service.stderr and "Traceback" not in service.stderr
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "name,value,replacement",
    [
        ("inject_sync_drop_every", "50", "RALF_FAULT_SCENARIO"),
        ("inject_delay_s", "0.3", "dsp_delay_s"),
        ("policy_deadline", "stop", "RALF_POLICIES=deadline="),
        ("oatf_frequency_hz", "5", "RALF_OATF=frequency_hz="),
        ("dither_amplitude_v", "0.01", "RALF_DITHER=amplitude_v="),
        ("rt_priority", "10", "RALF_REALTIME=priority="),
        ("search_min_hz", "1", "RALF_SEARCH_BAND_HZ="),
    ],
)
def test_a_retired_setting_ends_up_with_one_line_naming_its_replacement(name: str, value: str, replacement: str) -> None:
    """As an environment variable of ``ralf-hil up`` and as its ``--set``: exit 2 before anything starts."""
    for args, env in (([], _env(**{f"RALF_{name.upper()}": value})), (["--set", f"{name}={value}"], None)):
        proc = _run([*UP, "--clock", "lockstep", "--rig-id", _rig(), *args], env=env, timeout=60)
        said = " ".join((proc.stdout + proc.stderr).split())
        assert proc.returncode == 2 and replacement in said and "Traceback" not in said, said


def test_two_services_writing_one_file_are_refused_before_anything_starts(tmp_path: Path) -> None:
    env = _env(RALF_RUN_RECORD=str(tmp_path / "a.truth"), RALF_TRUTH_RECORD=str(tmp_path / "a"))
    proc = _run([*UP, "--clock", "lockstep", "--rig-id", _rig()], env=env, timeout=60)
    assert proc.returncode == 2 and "a.truth.npz would be written by both" in " ".join((proc.stdout + proc.stderr).split()), proc.stderr
    assert not list(tmp_path.iterdir())


@pytest.mark.timeout(300)
def test_one_record_path_for_the_whole_rig_gives_each_service_its_own_files(tmp_path: Path) -> None:
    """One environment for the whole rig, both record settings at one PATH: the
    controller's record and the plant's truth are both there, whole, and the
    run's credentials folder is gone after the run."""
    rec = tmp_path / "runs" / "rec"
    env = _env(RALF_RUN_RECORD=str(rec), RALF_TRUTH_RECORD=str(rec), RALF_DURATION_S="8", RALF_TF_DOWNLOAD_SAMPLES="400", RALF_FFT_WIDTH="512")
    proc = _run([*UP, "--clock", "lockstep", "--rig-id", _rig(), "--log-dir", str(tmp_path / "logs")], env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    written = {p.name for p in rec.parent.iterdir()}
    assert written == {"rec.npz", "rec.json", "rec.timing.npz", "rec.timing.json", "rec.tf.npz", "rec.truth.npz"}, written
    record = load_record(rec)
    assert len(record) == 1600 and record.metadata["result"]["ticks"] == 1600
    assert len(load_record(str(rec) + ".timing")) == 1600
    with np.load(rec.parent / "rec.truth.npz", allow_pickle=False) as truth:
        assert truth["sim_time_s"].size >= 150 and truth["sim_time_s"][-1] <= 8.0 + 1e-9
    with np.load(rec.parent / "rec.tf.npz", allow_pickle=False) as tf:
        assert tf["sim_time_s"].size >= 3
    access = _access_dir(proc.stdout + proc.stderr)
    assert not access.exists()  # removed at exit: nothing asked to keep it


def _files(root: Path) -> Iterator[Path]:
    for p in root.rglob("*"):
        if p.is_file():
            yield p


@pytest.mark.timeout(300)
def test_no_password_in_any_file_or_output_of_a_recorded_run(tmp_path: Path) -> None:
    out = tmp_path / "out"
    rec = out / "records" / "run"
    args = [*UP, "--clock", "lockstep", "--rig-id", _rig(), "--log-dir", str(out / "logs"), "--record", str(out / "run.mcap")]
    args += ["--json", str(out / "summary.json"), "--keep-credentials"]
    for item in (f"controller.run_record={rec}", f"plant.truth_record={rec}", "controller.duration_s=6", "dsp.fft_width=512"):
        args += ["--set", item]
    proc = _run(args)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    access = _access_dir(proc.stdout + proc.stderr)
    try:
        assert stat.S_IMODE(access.stat().st_mode) == 0o700
        credentials = (access / "zenoh-credentials.txt").read_text()
        passwords = [line.split(":", 1)[1].encode() for line in credentials.splitlines() if ":" in line]
        assert len(passwords) >= 5 and all(len(p) >= 16 for p in passwords)
        files = list(_files(out))
        assert {"run.mcap", "summary.json", "run.json", "run.truth.npz", "controller.log"} <= {p.name for p in files}
        outputs = {"stdout": proc.stdout.encode(), "stderr": proc.stderr.encode()} | {str(p): p.read_bytes() for p in files}
        hits = [(where, n) for where, data in outputs.items() for n, pw in enumerate(passwords) if pw in data]
        assert not hits, hits
        # where the credentials live is not recorded either (only printed for the user, who asked to keep them)
        where = str(access).encode()
        assert not [name for name, data in outputs.items() if where in data and name not in ("stdout", "stderr")]
        config = json.loads((rec.parent / "run.json").read_text())["config"]
        assert config["zenoh_password"] == "**********" and config["zenoh_user"] == "controller"
        help_text = _run([sys.executable, "-m", "controller", "--help"], timeout=60).stdout
        assert all(pw.decode() not in help_text for pw in passwords)
    finally:
        for p in access.iterdir():
            p.unlink()
        access.rmdir()


def _children(pid: int) -> list[int]:
    out: list[int] = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        out += [int(c) for c in (task / "children").read_text().split()]
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.timeout(300)
def test_services_end_when_up_is_killed_and_its_cut_recording_reads(tmp_path: Path) -> None:
    mcap = tmp_path / "run.mcap"
    args = [*UP, "--rig-id", _rig(), "--log-dir", str(tmp_path / "logs"), "--record", str(mcap), "--set", "dsp.fft_width=512"]
    up = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=_env())
    lines: list[str] = []
    ready = threading.Event()

    def read() -> None:
        assert up.stdout is not None
        for line in up.stdout:
            lines.append(line)
            if "all services ready" in line:
                ready.set()

    threading.Thread(target=read, daemon=True).start()
    services: list[int] = []
    try:
        assert ready.wait(180), "".join(lines)
        time.sleep(4.0)  # some control and some recording
        services = [pid for pid in _children(up.pid) if _alive(pid)]
        assert len(services) == 3, (services, "".join(lines))
        os.kill(up.pid, signal.SIGKILL)
        up.wait(timeout=30)
        deadline = time.monotonic() + 60
        while any(_alive(pid) for pid in services) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not [pid for pid in services if _alive(pid)], "a service outlived its launcher"
    finally:
        for pid in [up.pid, *services]:
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
    logs = "".join((tmp_path / "logs" / f"{name}.log").read_text() for name in ("controller", "plant", "dsp"))
    assert "received SIGTERM" in logs or "launcher (pid" in logs
    doctor = _run([sys.executable, "-m", "workbench", "doctor", str(mcap)], timeout=120)
    assert doctor.returncode == 1 and "cut short" in doctor.stdout and "Traceback" not in doctor.stderr, doctor.stdout + doctor.stderr
    held = int(re.search(r"(\d+) messages in", doctor.stdout).group(1))  # type: ignore[union-attr]
    assert held > 100
    plot = _run([sys.executable, "-m", "workbench", "plot", str(mcap), "--out", str(tmp_path / "plots")], timeout=180)
    assert plot.returncode == 0 and "cut short" in plot.stderr, plot.stdout + plot.stderr
    replay = _run([sys.executable, "-m", "workbench", "replay", str(mcap)], timeout=180)
    assert replay.returncode == 0 and "cut short" in replay.stderr and "Traceback" not in replay.stderr, replay.stdout + replay.stderr
