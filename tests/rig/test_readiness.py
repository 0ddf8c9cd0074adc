"""service_kit.readiness: the ready line (start-up seconds, numba kernels
loaded and compiled, counted by numba itself), the ready file and the
healthcheck that reads it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from service_kit import readiness
from service_kit.readiness import Readiness, check, parse_ready_line, process_age_s

ROOT = Path(__file__).resolve().parents[2]


def test_the_ready_line_parses_back() -> None:
    ready = Readiness(seconds=3.25, cached=5, compiled=2, compiled_names=("a.f", "b.g"))
    line = f"2026-01-01 00:00:00,000 dsp INFO dsp: {ready.line()}"
    assert parse_ready_line("noise\n" + line + "\n") == Readiness(seconds=3.25, cached=5, compiled=2)
    assert parse_ready_line("no such line") is None


def test_process_age_from_proc(tmp_path: Path) -> None:
    """Field 22 of /proc/self/stat (clock ticks since boot) plus btime, against an injected clock."""
    (tmp_path / "self").mkdir()
    hz = os.sysconf("SC_CLK_TCK")
    fields = ["S"] + ["0"] * 18 + [str(50 * hz)] + ["0"] * 10  # state is field 3, starttime field 22
    (tmp_path / "self" / "stat").write_text("123 (a (strange) name) " + " ".join(fields) + "\n")
    (tmp_path / "stat").write_text("cpu 1 2 3\nbtime 1000\n")
    assert process_age_s(now=lambda: 1062.5, proc=tmp_path) == pytest.approx(12.5)


def test_process_age_of_this_process_is_plausible() -> None:
    assert 0.0 < process_age_s() < 24 * 3600


_KERNEL_MODULE = """
from numba import njit

@njit(cache=True)
def twice(x):
    return 2.0 * x
"""

_PROBE = """
import json, sys
from service_kit import readiness
readiness.watch_compiles()
import kern
kern.twice(1.5)
r = readiness.mark_ready("", age_s=0.0)
print(json.dumps({"compiled": r.compiled, "names": r.compiled_names, "cached": readiness.cache_hits([kern])}))
"""


def test_compiles_and_cache_loads_are_counted_by_numba_itself(tmp_path: Path) -> None:
    """The first process compiles the kernel (one numba:compile event, named);
    the second loads it from numba's on-disk cache (a cache hit, nothing compiled)."""
    (tmp_path / "kern.py").write_text(_KERNEL_MODULE)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])}

    def probe() -> dict:
        out = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=120, check=True)
        return json.loads(out.stdout.strip().splitlines()[-1])

    first = probe()
    assert first["compiled"] == 1 and first["names"] == ["kern.twice"] and first["cached"] == 0
    second = probe()
    assert second == {"compiled": 0, "names": [], "cached": 1}


def test_the_ready_file_and_its_check(tmp_path: Path) -> None:
    path = tmp_path / "ready"
    ok, why = check(path)
    assert not ok and "does not exist" in why
    readiness.mark_ready(str(path), age_s=1.0)
    assert json.loads(path.read_text())["pid"] == os.getpid()
    assert check(path) == (True, f"ready: process {os.getpid()}")
    assert check(path, alive=lambda pid: False)[0] is False
    path.write_text("{not json")
    ok, why = check(path)
    assert not ok and "unreadable" in why
    readiness.clear(str(path))
    assert not path.exists()
    readiness.clear(str(path))  # twice is fine


def test_the_healthcheck_command(tmp_path: Path) -> None:
    """What a container's healthcheck runs: exit 0 when ready, 1 with one line when not, 2 on misuse."""
    path = tmp_path / "ready"
    cmd = [sys.executable, "-m", "service_kit.readiness"]
    missing = subprocess.run([*cmd, str(path)], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert missing.returncode == 1 and missing.stderr.count("\n") == 1 and "does not exist" in missing.stderr
    path.write_text(json.dumps({"pid": os.getpid()}))
    assert subprocess.run([*cmd, str(path)], capture_output=True, timeout=60, cwd=ROOT).returncode == 0
    assert subprocess.run(cmd, capture_output=True, timeout=60, cwd=ROOT).returncode == 2
