"""The controller's XCP slave on a one-process lockstep rig, measured and
calibrated by pyxcp (a master nobody here wrote), over UDP and over TCP."""

from __future__ import annotations

import math
import socket
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pyxcp.daq_stim import DaqList
from pyxcp.master.errorhandler import SystemExit as XcpError

from controller.xcp_table import A2L_MODULE, controller_a2l, controller_layout
from service_kit.xcp.memory import ASAM_TYPES
from tests.xcp.rig_client import BackgroundRig, Collect, free_port, master, wait_for

LAYOUT = controller_layout()
DAQ_NAMES = ("tick", "t_s", "phi1", "phi_shaped1", "u1_v", "pi1_v", "ai1_word", "defl1_in", "ext2_in")
TS = 0.005


def address(name: str) -> int:
    return LAYOUT.by_name[name].address


def upload(x: Any, name: str) -> float:
    v = LAYOUT.by_name[name]
    return float(struct.unpack("<" + v.code, x.shortUpload(v.size, v.address))[0])


def refused_code(call: Any) -> int:
    with pytest.raises(XcpError) as info:
        call()
    return int(info.value.error_code)


@pytest.fixture(params=["UDP", "TCP"])
def protocol(request: pytest.FixtureRequest) -> str:
    return str(request.param)


def test_measure_and_calibrate(protocol: str, tmp_path: Path) -> None:
    port = free_port(socket.SOCK_DGRAM if protocol == "UDP" else socket.SOCK_STREAM)
    a2l = tmp_path / "controller.a2l"
    key = "xcp_udp_port" if protocol == "UDP" else "xcp_tcp_port"
    rig = BackgroundRig({"duration_s": 3600.0, key: port, "xcp_a2l": str(a2l)}).start()
    try:
        assert wait_for(a2l.exists, 120), "the controller did not come up"
        daq = DaqList(
            name="tick",
            event_num=0,
            stim=False,
            enable_timestamps=True,
            measurements=[(n, address(n), 0, ASAM_TYPES[LAYOUT.by_name[n].datatype][1]) for n in DAQ_NAMES],
            priority=0,
            prescaler=1,
        )
        irq_names = ("tick", "f_id_hz", "id_confidence")
        on_irq = DaqList(
            name="dsp_interrupt",
            event_num=1,
            stim=False,
            enable_timestamps=True,
            measurements=[(n, address(n), 0, ASAM_TYPES[LAYOUT.by_name[n].datatype][1]) for n in irq_names],
            priority=0,
            prescaler=1,
        )
        policy = Collect([daq, on_irq])
        with master(port, protocol, policy) as x:
            assert x.identifier(0) == A2L_MODULE
            assert x.identifier(1) == "controller"
            assert x.identifier(2) == str(a2l)
            udp, tcp = (port, 0) if protocol == "UDP" else (0, port)
            assert a2l.read_text() == controller_a2l(TS, udp, tcp)  # the file GET_ID names: the table's A2L with this run's port
            assert upload(x, "kp1") == 7.5  # the thesis's 7500 mV/rad, raw in V/rad
            assert upload(x, "ki2") == 4.166
            # refused writes, each with its XCP error code (the map is unchanged after them)
            assert refused_code(lambda: x.shortDownload(address("kp1"), 0, struct.pack("<d", -0.001))) == 0x22  # ERR_OUT_OF_RANGE
            assert refused_code(lambda: x.shortDownload(address("kp1"), 0, struct.pack("<d", math.nan))) == 0x22
            assert refused_code(lambda: x.shortDownload(address("tick"), 0, struct.pack("<I", 7))) == 0x23  # ERR_WRITE_PROTECTED
            assert refused_code(lambda: x.shortDownload(address("oatf_zeta"), 0, struct.pack("<d", 0.1))) == 0x24  # no OATF in this run
            assert refused_code(lambda: x.shortDownload(address("kp1") + 4, 0, b"\0\0\0\0")) == 0x24  # half a parameter
            assert refused_code(lambda: x.shortUpload(4, LAYOUT.end)) == 0x24  # outside the map
            assert upload(x, "kp1") == 7.5

            policy.setup()
            policy.start()
            assert wait_for(lambda: len(policy.samples) >= 200, 120), f"{len(policy.samples)} DAQ samples"
            # kp1 doubled, kp2 kept, ki1 zero: one write of three parameters, taken at one tick
            x.setMta(address("kp1"), 0)
            x.download(struct.pack("<ddd", 15.0, 6.25, 0.0))
            assert wait_for(lambda: upload(x, "ki1") == 0.0 and upload(x, "kp1") == 15.0, 60)
            n_after = len(policy.samples) + 100
            assert wait_for(lambda: len(policy.samples) >= n_after, 120)
            policy.stop()
        run = rig.stop()
    finally:
        rig.stop_event.set()

    counters = run.result.counters
    prefix = "xcp_udp_" if protocol == "UDP" else "xcp_tcp_"
    assert counters[prefix + "snapshots_dropped"] == 0
    assert counters[prefix + "daq_overloads"] == 0
    assert counters[prefix + "writes_refused"] == 6
    assert counters["xcp_calibrations_applied"] == 1
    record = run.controller.record

    # every sample there, once, in order; the slave's timestamps are the ticks' simulated times
    headers = [h[0] for h in daq.headers]
    rows = [dict(zip(headers, values, strict=True)) for n, _, values in policy.samples if n == 0]
    ticks = np.array([r["tick"] for r in rows])
    assert ticks[0] >= 0 and np.array_equal(ticks, np.arange(ticks[0], ticks[0] + len(ticks)))
    stamps = np.array([ts for n, ts, _ in policy.samples if n == 0])
    assert np.all(np.diff(stamps) > 0)
    # pyxcp counts them from the first sample, in ns; the slave's resolution is 1 µs
    assert np.array_equal(stamps - stamps[0], (np.round(ticks * TS * 1e6).astype(np.int64) - round(ticks[0] * TS * 1e6)) * 1000)
    # the values are the run record's at the same ticks (the same float64 bits)
    rec_ticks = record.column("tick")
    index = np.searchsorted(rec_ticks, ticks)
    assert np.array_equal(rec_ticks[index], ticks)
    for name in DAQ_NAMES:
        got = np.array([r[name] for r in rows], dtype=np.float64)
        assert np.array_equal(got, record.column(name)[index]), name

    # event 1: the ticks at which a new DSP interrupt was taken; the record's interrupt columns change at those ticks only
    irq_headers = [h[0] for h in on_irq.headers]
    irq_rows = [dict(zip(irq_headers, values, strict=True)) for n, _, values in policy.samples if n == 1]
    irq_ticks = np.array([r["tick"] for r in irq_rows])
    assert len(irq_ticks) >= 3 and np.all(np.diff(irq_ticks) > 0)
    assert counters[prefix + "dtos_sent"] == len(ticks) + len(irq_ticks)
    f_id, confidence = record.column("f_id_hz"), record.column("id_confidence")
    changed = ~((f_id[1:] == f_id[:-1]) | (np.isnan(f_id[1:]) & np.isnan(f_id[:-1]))) | (confidence[1:] != confidence[:-1])
    changed_ticks = rec_ticks[1:][changed]
    window = changed_ticks[(changed_ticks > irq_ticks[0]) & (changed_ticks <= irq_ticks[-1])]
    assert set(window.tolist()) <= set(irq_ticks.tolist())
    i_irq = np.searchsorted(rec_ticks, irq_ticks)
    for name in irq_names:
        got = np.array([r[name] for r in irq_rows], dtype=np.float64)
        assert np.array_equal(got, record.column(name)[i_irq], equal_nan=True), name

    # the write, in the record from the tick it names on
    (change,) = [c for c in run.result.config_changes if c.kind == "xcp"]
    assert change.fields == {"kp1": 15000.0, "kp2": 6250.0, "ki1": 0.0}
    k = round(change.sim_time_s / TS)
    assert k > ticks[0]
    err = record.column("phi_shaped1") - record.column("phi1")
    expected = np.clip(15.0 * err, -10.0, 10.0)
    pi1 = record.column("pi1_v")
    after = rec_ticks >= k
    assert after.sum() >= 50
    np.testing.assert_allclose(pi1[after], expected[after], rtol=1e-12, atol=1e-15)
    before = (rec_ticks < k) & (rec_ticks >= k - 20)
    assert not np.allclose(pi1[before], expected[before], rtol=1e-9, atol=0.0)


def test_oatf_design_calibrated(tmp_path: Path) -> None:
    """A run with a fixed OATF: its first stage's frequency written over XCP is the
    record's ``oatf_hz`` from the tick the change is listed at; a design the
    filter's guards refuse is answered ERR_OUT_OF_RANGE and changes nothing."""
    port = free_port(socket.SOCK_DGRAM)
    a2l = tmp_path / "controller.a2l"
    rig = BackgroundRig({"duration_s": 3600.0, "oatf_mode": "fixed", "xcp_udp_port": port, "xcp_a2l": str(a2l)}).start()
    try:
        assert wait_for(a2l.exists, 120), "the controller did not come up"
        with master(port, "UDP") as x:
            assert upload(x, "oatf_frequency_hz") == 4.4 and upload(x, "oatf_zeta") == 0.09
            assert wait_for(lambda: upload(x, "tick") >= 50, 120)
            # 0.5 Hz with the stage's kept delay: sum|a| far above the guard's 4
            assert refused_code(lambda: x.shortDownload(address("oatf_frequency_hz"), 0, struct.pack("<d", 0.5))) == 0x22
            assert refused_code(lambda: x.shortDownload(address("oatf_zeta"), 0, struct.pack("<d", 0.99))) == 0x22  # above the table's limit
            x.shortDownload(address("oatf_frequency_hz"), 0, struct.pack("<d", 3.0))
            assert wait_for(lambda: upload(x, "oatf_hz") == 3.0, 60)
            target = upload(x, "tick") + 50
            assert wait_for(lambda: upload(x, "tick") >= target, 120)
        run = rig.stop()
    finally:
        rig.stop_event.set()
    (change,) = [c for c in run.result.config_changes if c.kind == "xcp"]
    assert change.fields == {"oatf_frequency_hz": 3.0}
    k = round(change.sim_time_s / TS)
    ticks, oatf_hz = run.controller.record.column("tick"), run.controller.record.column("oatf_hz")
    assert np.all(oatf_hz[ticks < k] == 4.4) and np.all(oatf_hz[ticks >= k] == 3.0)
    assert (ticks >= k).sum() >= 50 and (ticks < k).sum() >= 50
    assert run.result.counters["xcp_udp_writes_refused"] == 2
