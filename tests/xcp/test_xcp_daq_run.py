"""A whole 10-s run at 200 Hz measured by pyxcp over UDP: the lockstep loop
waits before tick 0 until the master's DAQ is running, then 2000 ticks; every
sample arrives once, timestamps step by the sample period, the values are the
run record's at the same ticks (the same float64 bits)."""

from __future__ import annotations

import socket
import threading
from pathlib import Path

import numpy as np
from pyxcp.daq_stim import DaqList

from controller.xcp_table import controller_layout
from service_kit.xcp.memory import ASAM_TYPES
from tests.xcp.rig_client import BackgroundRig, Collect, free_port, master, wait_for

LAYOUT = controller_layout()
TS = 0.005
TICKS = 2000
NAMES = ("tick", "t_s", "phi_ref1", "phi1", "phi2", "u1_v", "u2_v", "pi1_v", "ai1_word", "ai2_word", "defl1_in", "ext1_in")


def test_ten_seconds_of_daq(tmp_path: Path) -> None:
    port = free_port(socket.SOCK_DGRAM)
    a2l = tmp_path / "controller.a2l"
    daq_running = threading.Event()
    rig = BackgroundRig(
        {"duration_s": TICKS * TS, "xcp_udp_port": port, "xcp_a2l": str(a2l)},
        at_tick=(0, lambda: daq_running.wait(120)),  # the loop holds before tick 0 (simulated time does not move)
    ).start()
    measurements = [(n, LAYOUT.by_name[n].address, 0, ASAM_TYPES[LAYOUT.by_name[n].datatype][1]) for n in NAMES]
    daq = DaqList(name="tick", event_num=0, stim=False, enable_timestamps=True, measurements=measurements, priority=0, prescaler=1)
    policy = Collect([daq])
    try:
        assert wait_for(a2l.exists, 120), "the controller did not come up"
        with master(port, "UDP", policy, disconnect=False):  # the slave ends with the run
            policy.setup()
            policy.start()
            daq_running.set()
            assert wait_for(lambda: rig.run is not None or rig.error is not None, 300), "the run did not end"
            assert wait_for(lambda: len(policy.samples) >= TICKS, 30), f"{len(policy.samples)} samples"
        run = rig.stop()
    finally:
        daq_running.set()
        rig.stop_event.set()

    record = run.controller.record
    assert np.array_equal(record.column("tick"), np.arange(TICKS))
    headers = [h[0] for h in daq.headers]
    rows = [dict(zip(headers, values, strict=True)) for _, _, values in policy.samples]
    assert len(rows) == TICKS
    ticks = np.array([r["tick"] for r in rows])
    assert np.array_equal(ticks, np.arange(TICKS))  # each tick once, in order, none missing
    stamps = np.array([ts for _, ts, _ in policy.samples], dtype=np.int64)
    assert np.all(np.diff(stamps) > 0)
    assert np.array_equal(stamps - stamps[0], np.round(ticks * TS * 1e6).astype(np.int64) * 1000)  # µs on the rig's clock, in ns
    for name in NAMES:
        got = np.array([r[name] for r in rows], dtype=np.float64)
        assert np.array_equal(got, record.column(name)), name
    counters = run.result.counters
    # the result's counters are read as the loop ends, while the last samples may still be on their way out
    assert counters["xcp_udp_dtos_sent"] <= TICKS and counters["xcp_udp_snapshots_dropped"] == 0 and counters["xcp_udp_daq_overloads"] == 0
