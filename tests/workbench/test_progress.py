"""Progress for a log that is not a terminal: the heartbeat's interval on an
injected clock, the start-up lines taken from the services' logs."""

from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import pytest

from protocol.messages import ControllerStatus
from workbench.progress import Heartbeat, ServiceLogWatch, WatchedStream, activity, current_activity, heartbeat_unless_terminal, status_progress


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_line_is_written_only_after_the_interval_of_silence() -> None:
    clock, lines = FakeClock(), list[str]()
    beat = Heartbeat(lines.append, "ralf-hil up", interval_s=5.0, clock=clock)
    clock.now += 4.9
    assert not beat.check() and lines == []
    clock.now += 0.1
    assert beat.check() and lines == ["ralf-hil up: 5 s, running\n"]
    clock.now += 4.0
    assert not beat.check()  # the interval counts from the last line
    clock.now += 1.0
    assert beat.check() and len(lines) == 2 and lines[-1].startswith("ralf-hil up: 10 s")


def test_any_output_restarts_the_interval() -> None:
    clock, lines, log = FakeClock(), list[str](), io.StringIO()
    beat = Heartbeat(lines.append, "ralf-hil bench", interval_s=5.0, clock=clock)
    stream = WatchedStream(log, beat)
    clock.now += 4.0
    stream.write("item 1 done\n")
    clock.now += 4.0
    assert not beat.check() and lines == []  # 4 s since the command's own line
    clock.now += 1.0
    assert beat.check()
    assert log.getvalue() == "item 1 done\n" and stream.isatty() is False  # everything else passes through


def test_the_line_says_the_innermost_activity() -> None:
    clock, lines = FakeClock(), list[str]()
    beat = Heartbeat(lines.append, "ralf-hil experiment", interval_s=5.0, clock=clock)
    with activity("experiment id_lag"):
        with activity(lambda: "noise draws 3/10"):
            assert current_activity() == "noise draws 3/10"
            clock.now += 5.0
            beat.check()
        assert current_activity() == "experiment id_lag"
    assert current_activity() == ""
    assert lines == ["ralf-hil experiment: 5 s, noise draws 3/10\n"]


def test_a_failing_description_gives_a_plain_line() -> None:
    with activity(lambda: str(1 / 0)):
        assert current_activity() == ""


def test_a_rigs_progress_names_simulated_time_ticks_and_misses() -> None:
    status = ControllerStatus(seq=7, sim_time_s=12.5, ticks=2500, loop_rate_hz=200.0, batches_sent=83, interrupts=82, deadline_misses=1, overruns=4)
    assert status_progress(status) == "sim 12.50 s, ticks 2500, deadline misses 1, overruns 4, batches 83, interrupts 82"
    assert status_progress(None, waiting="starting") == "starting"


def test_start_up_lines_come_from_the_services_logs_once_each(tmp_path: Path) -> None:
    dsp, plant = tmp_path / "dsp.log", tmp_path / "plant.log"
    watch = ServiceLogWatch({"dsp": dsp, "plant": plant, "controller": tmp_path / "controller.log"})
    assert watch.events() == []  # no log yet: nothing, no error
    dsp.write_text("12:00:00 dsp INFO readiness: compiling the numba kernels (fft_step first), once: ~30-60 s; later runs load them\n")
    plant.write_text("12:00:00 plant INFO readiness: ready in 2.10 s (process start to ready); numba kernels: 3 loaded from cache, 0 compiled\n12:00:01 pl")
    assert watch.events() == [
        "dsp: compiling the numba kernels (first run, or a stale cache), once: ~30-60 s",
        "plant: ready in 2.10 s (process start to ready); numba kernels: 3 loaded from cache, 0 compiled",
    ]
    with open(dsp, "a") as fh:  # a second compile line says nothing new; a ready line split across two reads is read whole
        fh.write("compiling the numba kernels (arx first), once\nready in 41.")
    assert watch.events() == []
    with open(dsp, "a") as fh:
        fh.write("50 s (process start to ready); numba kernels: 0 loaded from cache, 5 compiled\n")
    assert watch.events() == ["dsp: ready in 41.50 s (process start to ready); numba kernels: 0 loaded from cache, 5 compiled"]


def test_one_heartbeat_per_process_and_none_on_a_terminal(monkeypatch: pytest.MonkeyPatch) -> None:
    log = io.StringIO()
    monkeypatch.setattr(sys, "stderr", log)
    with heartbeat_unless_terminal("ralf-hil up", interval_s=3600) as outer:
        assert outer is not None and isinstance(sys.stderr, WatchedStream)
        with heartbeat_unless_terminal("ralf-hil up", interval_s=3600) as inner:
            assert inner is outer  # the command's own wrap inside the entry point's: the same beat, no second wrapper
        assert isinstance(sys.stderr, WatchedStream)
        print("a line", file=sys.stderr)
    assert sys.stderr is log and log.getvalue() == "a line\n"

    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.setattr(sys, "stderr", Terminal())
    with heartbeat_unless_terminal("ralf-hil up") as beat:
        assert beat is None and isinstance(sys.stderr, Terminal)


def test_the_entry_module_loads_only_light_modules() -> None:
    code = "import sys, workbench.progress; print(sorted(m for m in ('pydantic', 'zenoh', 'numpy', 'rich', 'protocol.messages') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True).stdout
    assert out.strip() == "[]"  # the heartbeat starts before the rig's modules load
