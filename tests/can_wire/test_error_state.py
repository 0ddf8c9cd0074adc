"""Fault confinement (CAN 2.0 part B section 8 / ISO 11898-1): the counters'
thresholds, and a bus-off -> recovery timeline on the simulated bus worked
out in bit times from the rules."""

from __future__ import annotations

import pytest

from service_kit.can_wire.arbitration import ErrorInjection, QueuedFrame, simulate
from service_kit.can_wire.bits import frame_bits
from service_kit.can_wire.error_state import ErrorState, FaultConfinement
from service_kit.can_wire.timing import bit_time_ns


def test_transmit_error_thresholds() -> None:
    fc = FaultConfinement()
    for _ in range(15):
        fc.transmit_error()
    assert (fc.tec, fc.state) == (120, ErrorState.ACTIVE)
    fc.transmit_error()
    assert (fc.tec, fc.state) == (128, ErrorState.PASSIVE)  # rule 9: 128 and above
    fc.transmit_success()
    assert (fc.tec, fc.state) == (127, ErrorState.ACTIVE)  # rule 11
    for _ in range(16):
        fc.transmit_error()
    assert (fc.tec, fc.state) == (255, ErrorState.PASSIVE)
    fc.transmit_error()
    assert fc.tec == 263 and fc.state is ErrorState.BUS_OFF  # rule 10: 256 and above
    fc.transmit_success()
    fc.receive_error()
    assert fc.state is ErrorState.BUS_OFF and fc.tec == 263  # a bus-off node takes part in nothing


def test_receive_counter_rules() -> None:
    fc = FaultConfinement()
    fc.receive_error()
    assert fc.rec == 1
    fc.receive_error(dominant_after_flag=True)
    assert fc.rec == 9  # rule 2
    fc.receive_success()
    assert fc.rec == 8  # rule 8
    fc.rec = 140
    assert fc.state is ErrorState.PASSIVE
    fc.receive_success()
    assert (fc.rec, fc.state) == (127, ErrorState.ACTIVE)
    low = FaultConfinement(rec=200, rec_after_passive_success=119)
    low.receive_success()
    assert low.rec == 119
    fc.rec = 0
    fc.receive_success()
    assert fc.rec == 0
    with pytest.raises(ValueError):
        FaultConfinement(rec_after_passive_success=118)


def test_ack_error_exception_for_passive_transmitter() -> None:
    """Rule 3 exception 1: an error-passive transmitter's ACK error with no
    dominant bit during its passive flag leaves the TEC alone."""
    fc = FaultConfinement(tec=128)
    fc.transmit_error(ack_error=True)
    assert fc.tec == 128
    fc.transmit_error(ack_error=True, dominant_during_passive_flag=True)
    assert fc.tec == 136
    active = FaultConfinement(tec=120)
    active.transmit_error(ack_error=True)
    assert active.tec == 128


def test_recovery_needs_128_runs_of_11_recessive_bits() -> None:
    fc = FaultConfinement(tec=255)
    fc.transmit_error()
    assert fc.state is ErrorState.BUS_OFF
    assert fc.monitor([1] * 10 + [0] + [1] * 10) is None  # a dominant bit restarts the run
    assert fc.recovery_sequences == 0
    assert fc.idle_bits_to_recover() == 128 * 11 - 10
    assert fc.monitor_idle(128 * 11 - 11) is None
    assert fc.monitor([1]) == 1
    assert (fc.state, fc.tec, fc.rec) == (ErrorState.ACTIVE, 0, 0)


def test_bus_off_and_recovery_timeline_in_bit_times() -> None:
    """Node "a" sends one frame; the first 32 attempts are destroyed by a CRC
    error (flag after the ACK delimiter), node "r" receives. Per attempt the
    bus carries E = (ACK delimiter index + 1) + 6 flag + 8 delimiter + 3
    intermission bits. Attempts 1-16 follow each other at once (error
    active); after the 16th (TEC 128) "a" is error passive and waits 8 bits
    more each time (suspend transmission); the 32nd error flag takes TEC to
    256, bus off. The error delimiter and intermission make the first of the
    128 runs of 11 recessive bits; 127 x 11 idle bits later "a" is error
    active again and sends the frame at once."""
    bitrate = 500_000
    bit = bit_time_ns(bitrate)
    frame = frame_bits(0x181, bytes(range(8)))
    sent = frame.ack_delimiter_index + 1
    e = sent + 6 + 8 + 3
    run = simulate(
        [QueuedFrame("a", 0, frame)],
        bitrate,
        nodes=["r"],
        errors=[ErrorInjection(arbitration_id=0x181, count=32)],
    )
    starts = [a.start_ns // bit for a in run.attempts]
    assert starts[:16] == [k * e for k in range(16)]
    assert starts[16:32] == [16 * e + 8 + k * (e + 8) for k in range(16)]
    start_32 = 31 * e + 128
    assert starts[31] == start_32
    assert [a.ok for a in run.attempts] == [False] * 32 + [True]
    changes = [(c.time_ns // bit, c.state, c.tec) for c in run.state_changes if c.node == "a"]
    flag = lambda k: starts[k - 1] + sent  # noqa: E731 - the flag of attempt k
    passive = [c for c in changes if c[1] is ErrorState.PASSIVE][0]
    assert passive == (flag(16), ErrorState.PASSIVE, 128)
    bus_off = [c for c in changes if c[1] is ErrorState.BUS_OFF][0]
    assert bus_off == (flag(32), ErrorState.BUS_OFF, 256)
    recovered_at = start_32 + e + 127 * 11
    assert (recovered_at, ErrorState.ACTIVE, 0) in changes
    assert starts[32] == recovered_at
    tx = run.transmissions[0]
    assert tx.attempts == 33 and tx.end_ns // bit == recovered_at + frame.n_bits
    assert run.counters["r"].rec == 31  # +1 per error, -1 for the frame received
    assert run.counters["a"].tec == 0


def test_lone_node_stays_error_passive() -> None:
    """Nobody acknowledges a lone transmitter: ACK errors take its TEC to
    128, then rule 3 exception 1 holds it there, never bus off; it retries
    until the run ends."""
    bitrate = 1_000_000
    run = simulate([QueuedFrame("a", 0, frame_bits(0x100, b"\x01"))], bitrate, until_ns=10_000_000)
    assert all(a.ack_error and not a.ok for a in run.attempts)
    assert len(run.attempts) > 40
    assert run.counters["a"].tec == 128 and run.counters["a"].state is ErrorState.PASSIVE
    assert run.unsent == [0]


def test_error_frame_cost_and_retransmission() -> None:
    bitrate = 250_000
    bit = bit_time_ns(bitrate)
    frame = frame_bits(0x200, b"\x10\x20")
    run = simulate(
        [QueuedFrame("a", 0, frame)],
        bitrate,
        nodes=["b"],
        errors=[ErrorInjection(bit=20, echo_bits=6)],
    )
    first, second = run.attempts
    assert first.bits == 21 + 6 + 6 + 8 + 3
    assert second.start_ns == first.end_ns and second.ok
    assert run.transmissions[0].response_ns == (first.bits + frame.n_bits) * bit
    with pytest.raises(ValueError, match="outside the frame"):
        simulate([QueuedFrame("a", 0, frame)], bitrate, nodes=["b"], errors=[ErrorInjection(bit=frame.n_bits)])


def test_errors_by_rate_by_id_and_at_a_time() -> None:
    bitrate = 1_000_000
    a = [QueuedFrame("a", k * 1_000_000, frame_bits(0x181, bytes([k]))) for k in range(30)]
    b = [QueuedFrame("b", k * 1_000_000 + 500_000, frame_bits(0x201, bytes([k]))) for k in range(30)]
    every_third = simulate(a + b, bitrate, errors=[ErrorInjection(arbitration_id=0x181, every=3, count=None)])
    failed = [x for x in every_third.attempts if not x.ok]
    attempts_181 = [x for x in every_third.attempts if x.arbitration_id == 0x181]
    assert [x.ok for x in attempts_181] == [(k + 1) % 3 != 0 for k in range(len(attempts_181))]  # retries count as attempts
    assert {x.arbitration_id for x in failed} == {0x181} and len(failed) >= 10
    assert len(every_third.transmissions) == 60
    window = simulate(a + b, bitrate, errors=[ErrorInjection(start_ns=10_000_000, end_ns=12_000_000, count=None)])
    # every attempt starting in the window fails (retries included), the first after it goes through
    assert all((not x.ok) == (10_000_000 <= x.start_ns < 12_000_000) for x in window.attempts)
    assert sum(not x.ok for x in window.attempts) > 4 and len(window.transmissions) == 60
    rated = [simulate(a + b, bitrate, errors=[ErrorInjection(probability=0.3, seed=7, count=None)]) for _ in range(2)]
    assert rated[0].attempts == rated[1].attempts
    assert 5 <= sum(not x.ok for x in rated[0].attempts) <= 40
    assert len(rated[0].transmissions) == 60


def test_an_injection_reused_gives_the_same_run() -> None:
    frames = [QueuedFrame("a", k * 500_000, frame_bits(0x181, bytes([k]))) for k in range(20)]
    spec = [ErrorInjection(probability=0.5, seed=3, count=4)]
    first = simulate(frames, 1_000_000, nodes=["b"], errors=spec)
    again = simulate(frames, 1_000_000, nodes=["b"], errors=spec)
    assert first.attempts == again.attempts and sum(not a.ok for a in first.attempts) == 4
