"""service_kit.realtime: measures applied where permitted, reported where not."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import pytest

from service_kit.realtime import GIL_SWITCH_INTERVAL_S, apply_realtime, parse_cpus


def test_parse_cpus() -> None:
    assert parse_cpus("") == () and parse_cpus("1") == (1,) and parse_cpus("0-2,5") == (0, 1, 2, 5)
    with pytest.raises(ValueError, match="cpus"):
        parse_cpus("one")


def test_measures_on_a_thread_of_their_own_fall_back_cleanly() -> None:
    """On a thread (SCHED_FIFO and affinity are per thread on Linux): pinning to a
    CPU we have works, to one we lack is reported, FIFO either works or is
    reported; nothing raises. The FIFO thread sleeps at once and ends."""
    out: dict[str, object] = {}

    def body() -> None:
        have = sorted(os.sched_getaffinity(0))
        out["ok"] = apply_realtime(priority=1, cpu_affinity=str(have[0]))
        out["missing"] = apply_realtime(priority=0, cpu_affinity="4095", freeze_gc=False)

    t = threading.Thread(target=body)
    t.start()
    t.join(10)
    ok, missing = out["ok"], out["missing"]
    assert ok.cpus and ok.gc_frozen  # type: ignore[union-attr]
    assert ok.fifo_priority == 1 or any("SCHED_FIFO" in n for n in ok.notes)  # type: ignore[union-attr]
    assert missing.cpus == () and missing.fifo_priority == 0 and any("not available" in n for n in missing.notes)  # type: ignore[union-attr]
    assert ok.as_counters()["rt_gc_frozen"] == 1  # type: ignore[union-attr]


def test_whole_process_drops_the_switch_interval_and_helpers_step_below_the_loop() -> None:
    """In a process of its own (the measure changes process-wide state): with
    SCHED_FIFO granted, the GIL switch interval drops, a thread started before
    the measure stays on the normal scheduler, a thread the loop creates later
    (zenoh creates its runtime's threads lazily) starts on the normal
    scheduler instead of inheriting the loop's FIFO, and a helper the loop
    starts steps one FIFO level below it; refused, nothing moves and the
    refusal is reported."""
    code = textwrap.dedent(
        """
        import json, os, sys, threading
        from service_kit.realtime import apply_realtime, helper_priority, lower_current_thread
        ready, done = threading.Event(), threading.Event()
        tid = []
        def idle():
            tid.append(threading.get_native_id()); ready.set(); done.wait(10)
        t = threading.Thread(target=idle); t.start(); ready.wait(10)
        m = apply_realtime(priority=2, whole_process=True, freeze_gc=False)
        other = os.sched_getscheduler(tid[0]), os.sched_getparam(tid[0]).sched_priority
        created = []
        def lazy():  # a thread the loop creates later (zenoh's, say): the loop's FIFO is not inherited
            created.append((os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))
        z = threading.Thread(target=lazy); z.start(); z.join(10)
        later = []
        def helper(priority):  # the loop's helper: one level below the loop
            lowered = lower_current_thread(priority)
            later.append((priority, lowered, os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0), os.sched_getparam(0).sched_priority))
        h = threading.Thread(target=helper, args=(helper_priority(),)); h.start(); h.join(10)
        done.set(); t.join(10)
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
        print(json.dumps({"fifo": m.fifo_priority, "switch": sys.getswitchinterval(), "other": other, "created": created[0],
                          "later": later[0], "FIFO": os.SCHED_FIFO, "notes": list(m.notes), "counters": m.as_counters()}))
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    if r["fifo"]:
        assert r["other"][0] != r["FIFO"]  # zenoh's threads stay on the normal scheduler
        assert r["created"] == [os.SCHED_OTHER, 0]  # so do those created after the loop went FIFO
        assert r["later"] == [1, True, r["FIFO"], 1]  # a helper started by the loop: one level below it
        assert r["switch"] == pytest.approx(GIL_SWITCH_INTERVAL_S) and r["counters"]["rt_switch_interval_us"] == 200
    else:
        assert r["other"][0] != r["FIFO"] and any("SCHED_FIFO" in n for n in r["notes"])
        assert r["later"][:2] == [0, False]  # nothing to lower on the normal scheduler


def test_pm_qos_cpu_latency_is_written_held_and_refusals_are_notes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """hold_cpu_latency writes the bound as PM QoS reads it (a native int32)
    and keeps the file open (closing it would end the request); a lower
    bound replaces a higher one, a higher one keeps the lower; where the
    device is refused, apply_realtime notes it and goes on."""
    import struct

    from service_kit import realtime

    monkeypatch.setattr(realtime, "_cpu_latency_fd", None)
    monkeypatch.setattr(realtime, "_cpu_latency_us", -1)
    device = tmp_path / "cpu_dma_latency"
    device.write_bytes(b"")
    assert realtime.hold_cpu_latency(20, device=str(device)) == 20
    assert struct.unpack("i", device.read_bytes()[:4]) == (20,)
    fd = realtime._cpu_latency_fd
    assert fd is not None and os.fstat(fd)  # still open: the request lasts while the process lives
    assert realtime.hold_cpu_latency(50, device=str(device)) == 20  # the stricter bound stays
    assert realtime.hold_cpu_latency(0, device=str(device)) == 0
    assert struct.unpack("i", device.read_bytes()[-4:]) == (0,)
    os.close(realtime._cpu_latency_fd)  # type: ignore[arg-type]
    monkeypatch.setattr(realtime, "_cpu_latency_fd", None)
    monkeypatch.setattr(realtime, "_cpu_latency_us", -1)
    monkeypatch.setattr(realtime, "CPU_LATENCY_DEVICE", str(tmp_path / "missing"))
    m = realtime.apply_realtime(cpu_latency_us=0, freeze_gc=False)
    assert m.cpu_latency_us == -1 and any("PM QoS" in n for n in m.notes)
    assert m.as_counters()["rt_cpu_latency_us"] == -1


def test_zenoh_sessions_use_no_shared_memory() -> None:
    """zenoh's shared-memory transport maps (mlock) a 16 MiB pool at a
    process's first large put and again in each peer at its first large
    receive: 12-19 ms with the process's mmap lock held, in the controller
    at its first batch. The rig's sessions move every payload over their
    links instead."""
    from protocol.settings import CommonSettings
    from service_kit.transport import zenoh_config

    shm = json.loads(zenoh_config(CommonSettings()).get_json("transport/shared_memory"))
    assert shm["enabled"] is False
