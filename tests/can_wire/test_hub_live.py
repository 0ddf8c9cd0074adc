"""The arbiter's figures per period (service_kit/can_wire/hub_live.py) and their
way to the launcher (workbench/rig_wire.py): deterministic on a manual clock,
checked against the deliveries' own timestamps, the bus model's frame lengths
and the recording's JSON schema (jsonschema)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace

import jsonschema

from service_kit.can_wire.arbitration import INTERMISSION_BITS
from service_kit.can_wire.bits import frame_bits
from service_kit.can_wire.hub import Hub
from service_kit.can_wire.hub_live import PeriodFigures, publish_periodically
from service_kit.can_wire.wire_bus import ManualWireClock
from tests.can_wire.test_hub import BIT_NS, BITRATE, TPDO1, Endpoint, msg, plant_answering_sync, run_clock
from workbench.recording.schemas import CAN_BUS_LOAD_SCHEMA
from workbench.rig_wire import RigWire, WireRequest

CYCLE_NS = 1_000_000
PERIOD_NS = 5 * CYCLE_NS


def _rig(clock: ManualWireClock) -> tuple[Hub, Endpoint]:
    hub = Hub(BITRATE, clock=clock, window_ns=CYCLE_NS)
    master = Endpoint("controller")
    for ep in (master, plant_answering_sync(hub)):
        hub.attach(ep)
    return hub, master


def _cycles(hub: Hub, clock: ManualWireClock, master: Endpoint, first: int, n: int) -> None:
    for k in range(first, first + n):
        clock.advance_to(k * CYCLE_NS)
        assert hub.submit(master, msg(0x080))
        run_clock(clock)


def test_each_period_holds_its_own_frames_and_sync_to_tpdo1() -> None:
    clock = ManualWireClock()
    hub, master = _rig(clock)
    figures = PeriodFigures(hub, 0)
    _cycles(hub, clock, master, 0, 5)
    first = figures.next(PERIOD_NS)
    _cycles(hub, clock, master, 5, 3)
    second = figures.next(2 * PERIOD_NS)
    quiet = figures.next(3 * PERIOD_NS)

    sync, tpdo = frame_bits(0x080, b""), frame_bits(0x181, TPDO1)
    for record, cycles in ((first, 5), (second, 3)):
        jsonschema.validate(record, CAN_BUS_LOAD_SCHEMA)
        assert record["bitrate"] == BITRATE and record["frames"] == 2 * cycles
        bits = cycles * (sync.n_bits + tpdo.n_bits)
        assert record["bits_per_s"] == bits * 1e9 / PERIOD_NS
        assert record["frames_per_s"] == 2 * cycles * 1e9 / PERIOD_NS
        assert record["busy_mean_pct"] == 100 * bits * BIT_NS / PERIOD_NS  # frames never overlap: the busy time is their bits
        floor_us = (INTERMISSION_BITS + tpdo.n_bits_to_eof) * BIT_NS / 1e3
        assert record["sync_to_tpdo1_us"] == {"n": cycles, "p50": floor_us, "max": floor_us}
        assert record["sync_to_tpdo1_floor_margin_min_us"] == 0
        assert record["clients"]["connected"] == 2 and record["clients"]["overruns"] == 0
    assert (first["seq"], second["seq"], quiet["seq"]) == (1, 2, 3)
    # 1 ms windows from the first SOF, each holding one SYNC and its TPDO1: the period's peak window is its mean
    assert first["busy_max_pct"] == first["busy_mean_pct"]
    jsonschema.validate(quiet, CAN_BUS_LOAD_SCHEMA)
    assert quiet["frames"] == 0 and quiet["busy_mean_pct"] == 0 and "sync_to_tpdo1_us" not in quiet
    hub.close()


class _Stop:
    """A stop event that lets ``n`` periods pass, advancing the manual clock by one period each."""

    def __init__(self, n: int, on_period: Callable[[], None]) -> None:
        self.n, self.on_period = n, on_period

    def wait(self, _timeout: float) -> bool:
        if self.n == 0:
            return True
        self.n -= 1
        self.on_period()
        return False


def test_the_launcher_reads_each_published_period_once(tmp_path: Path) -> None:
    clock = ManualWireClock()
    hub, master = _rig(clock)
    wire = RigWire(WireRequest(BITRATE), tmp_path, tmp_path, SimpleNamespace(common_env={}))
    assert wire.poll_live() is None  # nothing published yet
    periods = iter(range(3))

    def period() -> None:
        k = next(periods)
        _cycles(hub, clock, master, 5 * k, 5)
        clock.advance_to((k + 1) * PERIOD_NS)

    publish_periodically(hub, wire.live_path, 1.0, _Stop(3, period))  # type: ignore[arg-type]
    last = wire.poll_live()
    assert last is not None and last["seq"] == 3 and last["frames"] == 10
    assert wire.poll_live() is None  # the same record is handed out once
    wire.live_path.write_text("{ half")
    assert wire.poll_live() is None  # not JSON: nothing, no error
    wire.live_path.write_text(json.dumps({**last, "seq": 4}))
    assert wire.poll_live() == {**last, "seq": 4}
    hub.close()


def test_the_live_view_has_the_channel_before_it_serves_only_with_a_wire() -> None:
    import argparse

    from workbench.cli import _start_live

    for wire, expected in ((WireRequest(BITRATE), True), (None, False)):
        args = argparse.Namespace(live="127.0.0.1:0", live_rate=10.0, rig_id="livechan", wire=wire)
        view = _start_live(args)
        try:
            assert ("/can/bus_load" in view._channels) is expected
        finally:
            view.close()
