"""Floods of allowed messages, injected with an injected clock: each
service's inputs are rate-limited per kind before decoding and hold a
bounded share of their inbox, every drop is counted, and the real messages
of other kinds still pass. No timed assertions: the work a flood can put on
a control thread is counted (messages decoded, items handed to the loop per
tick), not timed."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest
import zenoh

from plant_emulator.scenario import PendingCommands
from plant_emulator.service import SCENARIO_PENDING, PlantApplication
from protocol.keys import Keys
from protocol.messages import BlockFlag, ConfigChange, ScenarioCommand, decode, encode
from protocol.settings import PlantSettings
from service_kit.inbox import LIMITS, MAX_BYTES, Inbox, Limit, TokenBucket

FLOOD = 20_000
SPAN_S = 0.4
PERIOD_S = 0.005


class FakeClock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class Sample:
    """What a zenoh subscriber callback reads of a sample."""

    def __init__(self, payload: bytes) -> None:
        self.payload = payload
        self.attachment = None


def _flag(seq: int) -> bytes:
    return encode(BlockFlag(seq=seq, sim_time_s=0.0, state="empty", next_batch_seq=seq + 1, fft_width=256, batch_size=30))


def test_token_bucket_takes_a_burst_then_the_rate() -> None:
    bucket = TokenBucket(rate_per_s=10.0, burst=3)
    assert [bucket.take(0.0) for _ in range(5)] == [True, True, True, False, False]
    assert bucket.take(0.05) is False and bucket.take(0.1) is True  # one token per 0.1 s
    assert sum(bucket.take(10.0) for _ in range(10)) == 3  # never more than the burst after a pause
    assert bucket.take(9.0) is False  # a clock read out of order refills nothing


def test_limits_are_checked() -> None:
    with pytest.raises(ValueError):
        Limit(rate_per_s=0.0, burst=1)
    with pytest.raises(ValueError):
        Limit(rate_per_s=1.0, burst=0)


def test_a_command_flood_is_dropped_before_decoding_and_flags_keep_their_places() -> None:
    """The controller's inbox (its limits, capacity 256) under 20,000
    ConfigChange in 0.4 s with a flag every 5 ms, drained every 5 ms as the
    loop does: every command beyond the rate is counted and never decoded,
    no flag is dropped, and no tick is handed more than the burst of commands."""
    clock = FakeClock()
    inbox = Inbox("controller", capacity=256, clock=clock, limits=LIMITS)
    limit = LIMITS["command"]
    decoded = {"command": 0, "flag": 0}

    def decoder(kind: str, model: type) -> object:
        def run(raw: bytes) -> object:
            decoded[kind] += 1
            return decode(model, raw)

        return run

    command_cb = inbox.subscriber("command", decoder("command", ConfigChange))
    flag_cb = inbox.subscriber("flag", decoder("flag", BlockFlag))
    command = Sample(encode(ConfigChange(seq=0, sim_time_s=0.0)))
    per_tick: list[dict[str, int]] = []
    flags_sent = 0
    ticks = int(round(SPAN_S / PERIOD_S))
    per_period = FLOOD // ticks
    for tick in range(ticks):
        for n in range(per_period):
            clock.t = tick * PERIOD_S + n * PERIOD_S / per_period
            command_cb(command)
        flag_cb(Sample(_flag(flags_sent)))
        flags_sent += 1
        clock.t = (tick + 1) * PERIOD_S
        handed = inbox.drain(limit=inbox.capacity)  # the loop's tick
        per_tick.append({k: sum(1 for i in handed if i.kind == k) for k in ("command", "flag")})
    c, f = inbox.counters("command"), inbox.counters("flag")
    allowed = limit.burst + int(SPAN_S * limit.rate_per_s) + 1
    assert c.received == FLOOD and c.dropped_rate >= FLOOD - allowed
    assert c.queued + c.dropped_rate + c.dropped_full == FLOOD
    assert decoded["command"] == c.queued + c.dropped_full <= allowed  # the rest cost a counter, not a decode
    assert f.received == f.queued == flags_sent == sum(t["flag"] for t in per_tick) and f.dropped == 0
    assert max(t["command"] for t in per_tick) <= limit.burst
    assert inbox.as_dict()["in_command_dropped_rate"] == c.dropped_rate


def test_one_kind_cannot_fill_the_queue() -> None:
    clock = FakeClock()
    inbox = Inbox("t", capacity=16, clock=clock, limits={"command": Limit(rate_per_s=1e9, burst=10**6, queued=4)})
    for _ in range(100):
        inbox.put("command", object())
    for seq in range(12):
        assert inbox.put("flag", seq)
    assert inbox.counters("command").queued == 4 and inbox.counters("command").dropped_full == 96
    assert [i.kind for i in inbox.drain()].count("flag") == 12
    assert inbox.put("command", object())  # its places are free again once taken


def test_pending_scenario_commands_are_bounded_and_come_due_in_time_order() -> None:
    pending = PendingCommands(capacity=3)
    cmds = [ScenarioCommand(seq=s, sim_time_s=0.0, kind="seed", seed=s, at_sim_time_s=t) for s, t in ((0, 2.0), (1, 1.0), (2, 1.0), (3, 0.5))]
    assert [pending.add(c) for c in cmds] == [True, True, True, False]
    assert pending.dropped == 1 and len(pending) == 3
    assert pending.due(0.9) == []
    assert [c.seq for c in pending.due(1.0)] == [1, 2] and [c.seq for c in pending.due(5.0)] == [0]


def test_a_scenario_flood_leaves_the_plant_bounded_and_applies_the_real_command() -> None:
    """20,000 ScenarioCommands for the far future in 0.4 s on the plant's
    test port (its subscriber callback, clock injected), then one real
    command: the flood is counted and dropped at the rate limit, at most
    ``SCENARIO_PENDING`` wait, and the real one is applied at its time."""
    app = PlantApplication(PlantSettings(clock="lockstep"))
    clock = FakeClock()
    app.scenario_inbox = Inbox("plant", capacity=64, clock=clock, limits=LIMITS)
    on_sample = app.scenario_inbox.subscriber("scenario", lambda b: decode(ScenarioCommand, b))
    far = Sample(encode(ScenarioCommand(seq=0, sim_time_s=0.0, kind="seed", seed=1, at_sim_time_s=1e6)))
    for n in range(FLOOD):
        clock.t = n * SPAN_S / FLOOD
        on_sample(far)
        if n % 1000 == 0:
            app.on_sync(n // 1000)
    clock.t = 10.0  # the bucket has refilled
    assert on_sample(Sample(encode(ScenarioCommand(seq=1, sim_time_s=0.0, kind="payload", payload_attached=True, at_sim_time_s=0.2)))) is None
    tick = FLOOD // 1000
    while app.arm.time_s < 0.2 + 2 * app.sample_period_s:
        app.on_sync(tick)
        tick += 1
    counters = app.scenario_inbox.counters("scenario")
    assert counters.received == FLOOD + 1 and counters.dropped_rate >= FLOOD - LIMITS["scenario"].burst - int(SPAN_S * LIMITS["scenario"].rate_per_s) - 1
    assert counters.received == counters.queued + counters.dropped  # every one taken or counted
    assert len(app.scenario) <= SCENARIO_PENDING
    assert app.arm.payload_attached


@pytest.mark.rig
def test_a_command_flood_on_a_running_controller_is_counted_and_the_flags_pass(tmp_path: Path) -> None:
    """The in-process rig (lockstep, so the run is deterministic): 20,000
    ConfigChange on controller/command in the loop at tick 100 (one zenoh
    session: each put is delivered before it returns). The burst is taken,
    the rest is counted as over the rate, no flag or interrupt is dropped,
    and the run applies as many interrupts as an undisturbed one."""
    from workbench.composition import run_in_process

    spent: list[float] = []

    def run(name: str, attack: bool) -> dict[str, int]:
        config = zenoh.Config()
        config.insert_json5("mode", '"peer"')
        config.insert_json5("scouting/multicast/enabled", "false")
        config.insert_json5("listen/endpoints", json.dumps([]))
        session = zenoh.open(config)
        keys = Keys(f"cmd-flood-{name}")
        payload = encode(ConfigChange(seq=0, sim_time_s=0.0))

        def flood() -> None:
            start = time.monotonic()
            for _ in range(FLOOD):
                session.put(keys.controller_command, payload)
            spent.append(time.monotonic() - start)

        try:
            result = run_in_process(
                controller={"duration_s": 3.0, "tf_download_samples": 0},
                dsp={"fft_width": 256},
                common={"rig_id": keys.rig_id},
                session=session,
                at_tick=(100, flood) if attack else None,
            )
        finally:
            session.close()
        return result.result.counters

    quiet, noisy = run("quiet", False), run("noisy", True)
    limit = LIMITS["command"]
    # the arrivals are stamped on the wall clock: the bucket refills while the flood lasts
    taken = limit.burst + int(spent[0] * limit.rate_per_s) + 1
    assert noisy["reconfigurations"] <= taken and noisy["in_command_dropped_rate"] >= FLOOD - taken
    assert noisy["reconfigurations"] + noisy["in_command_dropped_rate"] + noisy.get("in_command_dropped_full", 0) == FLOOD
    assert noisy.get("in_flag_dropped_full", 0) == 0 and noisy.get("in_interrupt_dropped_full", 0) == 0
    assert noisy["interrupts_applied"] == quiet["interrupts_applied"] > 0
    assert MAX_BYTES["command"] > len(encode(ConfigChange(seq=0, sim_time_s=0.0)))


@pytest.mark.rig
def test_a_command_flood_over_a_zenoh_link_is_counted_exactly() -> None:
    """A service's session as the rig configures it (``zenoh_config``) and
    the controller's inbox (its ``LIMITS``) under 20,000 commands from a
    tool's session over TCP, a flag every 250 (both publishers blocking
    rather than dropping, so every put reaches the service): every command
    that arrives is counted, ``received == queued + dropped`` exactly, and
    ``received`` is all 20,000 (nothing is dropped before the inbox, where
    it would not be counted); every flag is queued."""
    from protocol.settings import CommonSettings
    from service_kit.transport import zenoh_config
    from workbench.launcher import free_tcp_port

    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    keys = Keys("tool-input-count")
    service = zenoh.open(zenoh_config(CommonSettings(rig_id=keys.rig_id, zenoh_listen=endpoint)))
    inbox = Inbox("controller", capacity=256, limits=LIMITS)
    subs = [
        service.declare_subscriber(keys.controller_command, inbox.subscriber("command", lambda b: decode(ConfigChange, b))),
        service.declare_subscriber(keys.flag, inbox.subscriber("flag", lambda b: decode(BlockFlag, b))),
    ]
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    tool = zenoh.open(config)
    flags = FLOOD // 250 + 1
    taken: list[object] = []
    try:
        block = zenoh.CongestionControl.BLOCK
        command = tool.declare_publisher(keys.controller_command, congestion_control=block)
        flag = tool.declare_publisher(keys.flag, congestion_control=block)
        deadline = time.monotonic() + 20
        while not (command.matching_status.matching and flag.matching_status.matching) and time.monotonic() < deadline:
            time.sleep(0.02)
        payload = encode(ConfigChange(seq=0, sim_time_s=0.0))
        start = time.monotonic()
        for n in range(FLOOD):
            command.put(payload)
            if n % 250 == 0:
                flag.put(_flag(n))
        flag.put(_flag(FLOOD))  # the last: everything before it on this link has been delivered
        deadline = time.monotonic() + 120  # bounded; a busy host delivers 20,000 puts in well over 30 s
        while inbox.counters("flag").received < flags and time.monotonic() < deadline:
            taken += inbox.drain()  # the loop's side: keeps the queue from filling with flags
            time.sleep(0.001)
        spent = time.monotonic() - start
        taken += inbox.drain()
    finally:
        tool.close()
        for sub in subs:
            sub.undeclare()
        service.close()
    c, f = inbox.counters("command"), inbox.counters("flag")
    assert c.received == FLOOD, c
    assert c.received == c.queued + c.dropped_rate + c.dropped_full and c.dropped == c.dropped_rate + c.dropped_full
    limit = LIMITS["command"]
    assert 1 <= c.queued <= limit.burst + limit.rate_per_s * spent + 1, (c, spent)
    assert f.received == f.queued == flags and f.dropped == 0
    assert sum(1 for i in taken if getattr(i, "kind", None) == "command") == c.queued
    assert inbox.as_dict()["in_dropped"] == c.dropped
