"""The DSP board's behaviour on zenoh (in-process session): flag sequence,
interrupts in order, protocol violations, run-time reconfiguration, TF queries."""

from __future__ import annotations

import dataclasses
import json
import queue
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import zenoh

from dsp_service.service import REANNOUNCE_S, DspService
from protocol.batch_codec import SampleBatch, encode_batch
from protocol.encodings import TF_MIME
from protocol.errors import ProtocolError
from protocol.keys import Keys
from protocol.messages import BlockFlag, ConfigChange, Interrupt, decode, encode
from protocol.settings import DspSettings
from protocol.tf_codec import decode_tf


@pytest.fixture
def session() -> Iterator[zenoh.Session]:
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps([]))
    s = zenoh.open(config)
    yield s
    s.close()


def _settings(**kw: object) -> DspSettings:
    base = {"rig_id": f"dsp-{time.monotonic_ns() % 10**9}", "fft_width": 256, "emulated_latency_s": 0.0, "clock": "lockstep", "health_period_s": 0.2}
    return DspSettings(**{**base, **kw})  # type: ignore[arg-type]


def _batch(seq: int, n: int = 20, rng: np.random.Generator | None = None) -> SampleBatch:
    rng = rng or np.random.default_rng(seq)
    return SampleBatch(
        seq=seq,
        first_tick=seq * n,
        sample_rate_hz=200.0,
        sim_time_s=seq * n / 200.0,
        wall_time_s=time.time(),
        inputs=rng.standard_normal((2, n)),
        outputs=rng.standard_normal((2, n)),
    )


class Probe:
    """Collects the board's flags and interrupts in arrival order."""

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self.events: queue.Queue[tuple[str, object]] = queue.Queue()
        self.subs = [
            session.declare_subscriber(keys.flag, lambda s: self.events.put(("flag", decode(BlockFlag, s.payload.to_bytes())))),
            session.declare_subscriber(keys.interrupt, lambda s: self.events.put(("irq", decode(Interrupt, s.payload.to_bytes())))),
        ]

    def next(self, kind: str, timeout: float = 5.0) -> object:
        deadline = time.monotonic() + timeout
        while True:
            k, msg = self.events.get(timeout=max(0.01, deadline - time.monotonic()))
            if k == kind:
                return msg

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()


@dataclass
class RunningBoard:
    keys: Keys
    service: DspService
    probe: Probe
    thread: threading.Thread
    pub: zenoh.Publisher | None  # a publisher on the batch key, when asked for


@contextmanager
def _running_board(session: zenoh.Session, settings: DspSettings, *, publisher: bool = False, inline: bool = False) -> Iterator[RunningBoard]:
    """A DspService serving on a thread, a Probe on its flags and interrupts (declared
    before the service, so the first flag is seen); on exit the service is stopped and
    joined, then the publisher, the probe and the service are closed."""
    keys = Keys(settings.rig_id)
    probe = Probe(session, keys)
    service = DspService(settings, session, inline=inline)
    stop = threading.Event()
    thread = threading.Thread(target=service.run, args=(stop,), daemon=True)
    thread.start()
    pub = session.declare_publisher(keys.batch) if publisher else None
    try:
        yield RunningBoard(keys, service, probe, thread, pub)
    finally:
        stop.set()
        thread.join(5)
        if pub is not None:
            pub.undeclare()
        probe.close()
        service.close()


@pytest.mark.parametrize("inline", [False, True])
def test_flag_sequence_and_interrupts_in_order(session: zenoh.Session, inline: bool) -> None:
    settings = _settings()
    with _running_board(session, settings, publisher=True, inline=inline) as board:
        probe, pub = board.probe, board.pub
        first = probe.next("flag")
        assert isinstance(first, BlockFlag) and first.state == "empty" and first.next_batch_seq == 0
        assert first.fft_width == 256
        log: list[tuple[str, object]] = []
        started = time.monotonic()
        for seq in range(15):
            pub.put(encode_batch(_batch(seq)))
            while True:  # wait for this batch's interrupt, keeping everything seen on the way
                kind, msg = probe.events.get(timeout=5)
                log.append((kind, msg))
                if kind == "irq":
                    break
        irqs = [m for k, m in log if k == "irq"]
        assert [i.batch_seq for i in irqs] == list(range(15))  # type: ignore[union-attr]
        assert [i.seq for i in irqs] == list(range(15))  # type: ignore[union-attr]
        assert all(i.compute_time_s > 0 and 0.0 <= i.confidence <= 1.0 for i in irqs)  # type: ignore[union-attr]
        # Fig. 3.5 step 4: the interrupt is the block's empty flag; no separate flag
        # follows a batch (only the start's, and a re-announce every REANNOUNCE_S,
        # which never runs ahead of the block).
        deadline = time.monotonic() + 0.2
        while time.monotonic() < deadline:
            try:
                log.append(probe.events.get(timeout=0.05))
            except queue.Empty:
                pass
        flags = [m for k, m in log if k == "flag"]
        reannounces = (time.monotonic() - started) / REANNOUNCE_S + 1
        assert len(flags) <= reannounces, [f.next_batch_seq for f in flags]  # type: ignore[attr-defined]
        assert all(f.state == "empty" for f in flags)  # type: ignore[attr-defined]
        irq = irqs[-1]
        assert irq.samples_in_history == 256  # 15 x 20 samples, history holds N


def test_violations_are_reported_not_merged(session: zenoh.Session) -> None:
    service = DspService(_settings(), session)
    try:
        assert service.process_batch(_batch(0)) is not None
        service.block.admit(_batch(1))  # the block is now full with batch 1
        assert service.process_batch(_batch(2)) is None
        assert service.block.counters.block_full_violations == 1
        service.block.release()
        irq = service.process_batch(_batch(5))  # batches 2..4 never arrived
        assert irq is not None and irq.batch_seq == 5
        assert service.block.counters.sequence_gaps == 1
        assert service.identifier.samples_in_history == 20  # history restarted at the gap
        health = service._build_health(0)
        assert health.counters["block_full_violations"] == 1 and health.last_miss
    finally:
        service.close()


def test_fft_width_change_zeroes_history_batch_size_change_keeps_it(session: zenoh.Session) -> None:
    service = DspService(_settings(), session)
    try:
        for seq in range(5):
            service.process_batch(_batch(seq))
        assert service.identifier.samples_in_history == 100
        service.apply_config(ConfigChange(seq=0, sim_time_s=0.5, batch_size=40))
        assert service.identifier.samples_in_history == 100 and service.batch_size == 40
        service.apply_config(ConfigChange(seq=1, sim_time_s=0.5, fft_width=128))
        assert service.identifier.fft_width == 128
        assert service.identifier.samples_in_history == 0
        assert len(service.snapshot().freqs_hz) == 65
    finally:
        service.close()


def test_undecodable_batches_are_counted_and_the_board_keeps_serving(session: zenoh.Session) -> None:
    settings = _settings()
    with _running_board(session, settings) as board:
        keys, service, probe = board.keys, board.service, board.probe
        probe.next("flag")
        session.put(keys.batch, b"RALB garbage")
        session.put(keys.dsp_config, b'{"seq": "x"}')
        session.put(keys.batch, encode_batch(_batch(0)))
        irq = probe.next("irq")
        assert irq.batch_seq == 0  # type: ignore[union-attr]
        deadline = time.monotonic() + 5  # the config key's callback is not ordered with the batch key's
        while service.block.counters.decode_errors < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert service.block.counters.decode_errors == 2


def test_tf_queryable_returns_the_current_estimates(session: zenoh.Session) -> None:
    settings = _settings()
    service = DspService(settings, session)
    try:
        rng = np.random.default_rng(7)
        for seq in range(30):
            service.process_batch(_batch(seq, rng=rng))
        replies = list(session.get(Keys(settings.rig_id).tf, timeout=5.0))
        assert str(replies[0].ok.encoding) == TF_MIME
        snap = decode_tf(replies[0].ok.payload.to_bytes())
        assert set(snap.estimates) == {"H11", "H12", "H21", "H22", "Htot"}
        assert len(snap.freqs_hz) == 129 and snap.freqs_hz[1] == pytest.approx(200.0 / 256)
        assert snap.batch_seq == 29
        assert all(np.isfinite(snap.estimates["Htot"].magnitude))
    finally:
        service.close()


def test_bad_settings_are_refused_with_the_variable_name() -> None:
    from protocol.errors import ConfigError
    from protocol.settings import load_settings

    with pytest.raises(ConfigError, match="RALF_FFT_WIDTH"):
        load_settings(DspSettings, {"fft_width": 1000})
    _ = encode  # the module's codec helpers are exercised above


def test_a_burst_over_zenoh_while_the_block_is_full_is_a_reported_violation(session: zenoh.Session) -> None:
    settings = _settings(fault_scenario='{"dsp_delay_s": 0.3}')  # the board is busy with batch 0 while the burst arrives
    with _running_board(session, settings, publisher=True) as board:
        service, probe, pub = board.service, board.probe, board.pub
        probe.next("flag")
        for seq in range(4):
            pub.put(encode_batch(_batch(seq)))
        first = probe.next("irq")
        assert first.batch_seq == 0  # type: ignore[union-attr]
        deadline = time.monotonic() + 5
        while service.block.counters.block_full_violations < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert service.block.counters.block_full_violations == 3  # batches 1..3 came while 0 was processed
        assert service.block.counters.batches_accepted == 1  # never merged
        assert service._build_health(0).counters["block_full_violations"] == 3
        # a batch arriving while full is rejected, not merged: the next one that comes shows the gap
        pub.put(encode_batch(_batch(4)))
        irq = probe.next("irq")
        assert irq.batch_seq == 4 and service.block.counters.sequence_gaps == 1  # type: ignore[union-attr]


def test_batches_the_board_cannot_identify_are_rejected_not_fatal(session: zenoh.Session) -> None:
    settings = _settings()
    with _running_board(session, settings) as board:
        keys, service, probe, thread = board.keys, board.service, board.probe, board.thread
        probe.next("flag")
        one_input = SampleBatch(seq=0, first_tick=0, sample_rate_hz=200.0, sim_time_s=0.0, wall_time_s=0.0, inputs=np.ones((1, 20)), outputs=np.ones((2, 20)))
        other_rate = SampleBatch(seq=0, first_tick=0, sample_rate_hz=1000.0, sim_time_s=0.0, wall_time_s=0.0, inputs=np.ones((2, 20)), outputs=np.ones((2, 20)))
        session.put(keys.batch, encode_batch(one_input))
        session.put(keys.batch, encode_batch(other_rate))
        session.put(keys.dsp_config, encode(ConfigChange(seq=0, sim_time_s=0.0, alpha=0.5, fft_width=32, batch_size=4096)))
        session.put(keys.batch, encode_batch(_batch(0)))
        assert probe.next("irq").batch_seq == 0  # type: ignore[union-attr]
        deadline = time.monotonic() + 5
        while service.block.counters.rejected < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert service.block.counters.rejected == 2
        assert thread.is_alive()


@pytest.mark.parametrize("inline", [False, True])
def test_the_emulated_latency_is_a_due_time_and_a_stop_is_seen_while_an_interrupt_is_held(session: zenoh.Session, inline: bool) -> None:
    """Real time, 10 s emulated latency (the bound): the board holds the
    interrupt with its block full, keeps taking events (a latency of 1e6 s is
    refused, counted), and stops at once when told (inline too: computed in
    zenoh's thread, held by the board's)."""
    settings = _settings(clock="realtime", emulated_latency_s=10.0)
    with _running_board(session, settings, publisher=True, inline=inline) as board:
        service, probe, pub, thread = board.service, board.probe, board.pub, board.thread
        probe.next("flag")
        pub.put(encode_batch(_batch(0)))
        deadline = time.monotonic() + 5
        while service.interrupt_seq == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert service.interrupt_seq == 1 and service.block.full  # computed, held until due
        # A latency of 1e6 s is out of the message's bounds: refused at the edge, counted.
        too_long = ConfigChange.model_construct(seq=0, sim_time_s=0.0, wall_time_s=0.0, emulated_latency_s=1e6, reset=False).model_dump_json().encode()
        session.put(board.keys.dsp_config, too_long)
        deadline = time.monotonic() + 5
        while service.block.counters.decode_errors == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert service.block.counters.decode_errors == 1 and service.emulated_latency_s == 10.0
        with pytest.raises(queue.Empty):
            probe.next("irq", timeout=0.3)  # not due yet
    # the context manager set stop and joined the thread for at most 5 s, half the interrupt's 10 s latency: the
    # board ended without waiting for the interrupt to come due (no wall-clock bound of its own: a loaded host
    # may take its time to schedule the thread)
    assert not thread.is_alive() and service.interrupt_seq == 1


@pytest.mark.parametrize("inline", [False, True])
def test_an_inline_board_answers_in_zenohs_thread_with_one_interrupt_and_no_flag(session: zenoh.Session, inline: bool) -> None:
    """Without the board's thread running, only an inline board (one rig)
    answers a batch: it identified it in the subscriber callback and sent the
    interrupt, which flags the block empty (no separate flag follows)."""
    settings = _settings()
    keys = Keys(settings.rig_id)
    probe = Probe(session, keys)
    service = DspService(settings, session, inline=inline)
    pub = session.declare_publisher(keys.batch)
    try:
        pub.put(encode_batch(_batch(0)))
        if not inline:
            with pytest.raises(queue.Empty):
                probe.events.get(timeout=0.5)
            assert service.interrupt_seq == 0 and service.block.full  # waiting for the board's thread
            return
        kind, irq = probe.events.get(timeout=5)
        assert kind == "irq" and irq.batch_seq == 0  # type: ignore[attr-defined]
        with pytest.raises(queue.Empty):
            probe.events.get(timeout=0.3)  # no flag after the interrupt (the board's thread, which re-announces, is not running)
        # the bookkeeping comes after the put, on the callback's thread: wait for it (bounded)
        deadline = time.monotonic() + 5.0
        while service.turnaround.stats().count == 0 and time.monotonic() < deadline:
            time.sleep(0.001)
        assert not service.block.full and service.turnaround.stats().count == 1
    finally:
        pub.undeclare()
        probe.close()
        service.close()


def test_a_batch_sent_again_gets_the_same_interrupt_again(session: zenoh.Session) -> None:
    """The CPU resends the batch in flight when its interrupt was lost: the
    board answers with the interrupt it raised, never identifies twice."""
    settings = _settings()
    with _running_board(session, settings, publisher=True) as board:
        service, probe, pub = board.service, board.probe, board.pub
        probe.next("flag")
        pub.put(encode_batch(_batch(0)))
        first = probe.next("irq")
        pub.put(encode_batch(_batch(0)))
        again = probe.next("irq")
        assert again == first  # type: ignore[comparison-overlap]
        assert service.block.counters.interrupts_repeated == 1 and service.block.counters.batches_accepted == 1
        assert service.block.counters.duplicates == 0 and service.interrupt_seq == 1


def test_one_process_serves_several_rigs_and_a_stuck_rig_delays_no_other(session: zenoh.Session, monkeypatch: pytest.MonkeyPatch) -> None:
    """``serve_rigs``: one board per rig on one session (``dsp_service.__main__.serve``). While
    one rig's step is stuck (held here until released), the other rigs' batches are answered:
    each rig has its own queue and thread."""
    from dsp_service import __main__ as dsp_main
    from dsp_service.core import DspCore

    settings = _settings(serve_rigs="")
    slow, fast = settings.rig_id, [f"{settings.rig_id}-b", f"{settings.rig_id}-c"]
    settings = _settings(rig_id=slow, serve_rigs=",".join(fast))
    assert settings.rig_ids == (slow, *fast)
    entered, release = threading.Event(), threading.Event()
    original = DspCore.process_fields

    def process_fields(core: DspCore, batch: SampleBatch, admission: object) -> dict[str, object]:
        if core.settings.rig_id == slow:
            entered.set()
            assert release.wait(30.0), "the stuck rig was never released"
        return original(core, batch, admission)  # type: ignore[arg-type]

    monkeypatch.setattr(DspCore, "process_fields", process_fields)
    probes = {rig: Probe(session, Keys(rig)) for rig in (slow, *fast)}
    pubs = {rig: session.declare_publisher(Keys(rig).batch) for rig in (slow, *fast)}
    stop = threading.Event()
    thread = threading.Thread(target=dsp_main.serve, args=(settings, session, stop), daemon=True)
    thread.start()
    try:
        for rig in (slow, *fast):
            assert probes[rig].next("flag", timeout=60.0).state == "empty"  # type: ignore[attr-defined]
        pubs[slow].put(encode_batch(_batch(0)))
        assert entered.wait(10.0)
        for seq in range(3):  # the other rigs go on while the first is stuck
            for rig in fast:
                pubs[rig].put(encode_batch(_batch(seq)))
                irq = probes[rig].next("irq")
                assert isinstance(irq, Interrupt) and irq.batch_seq == seq
                while probes[rig].next("flag").state != "empty":  # type: ignore[attr-defined]
                    pass
        assert all(kind == "flag" for kind, _ in list(probes[slow].events.queue))  # no interrupt yet
        release.set()
        irq = probes[slow].next("irq")
        assert isinstance(irq, Interrupt) and irq.batch_seq == 0
    finally:
        release.set()
        stop.set()
        thread.join(10)
        for pub in pubs.values():
            pub.undeclare()
        for probe in probes.values():
            probe.close()
    assert not thread.is_alive()


def test_serve_rigs_are_validated() -> None:
    with pytest.raises(ValueError, match="twice"):
        _settings(serve_rigs="a,b,a")
    with pytest.raises(ValueError, match="rig id"):
        _settings(serve_rigs="a,b/c")
    assert _settings(rig_id="x", serve_rigs=" a , b ").rig_ids == ("x", "a", "b")


def test_access_rules_cover_every_rig_a_dsp_serves(tmp_path: Path) -> None:
    """The DSP session's access control (service_kit.access) carries each served rig's rules:
    on every rig's flag and interrupt keys only the dsp role may publish, on its batch key only the controller."""
    from service_kit.transport import zenoh_config

    files = {name: tmp_path / name for name in ("ca.pem", "dsp.pem", "dsp.key")}
    for path in files.values():
        path.write_text("-----BEGIN-----\n")  # read by zenoh only when a session opens
    tls = {"zenoh_tls_ca": files["ca.pem"], "zenoh_tls_certificate": files["dsp.pem"], "zenoh_tls_key": files["dsp.key"]}
    settings = _settings(rig_id="r0", serve_rigs="r1,r2", zenoh_acl=True, **{k: str(v) for k, v in tls.items()})
    acl = json.loads(zenoh_config(settings).get_json("access_control"))
    rule_ids = {r["id"]: r for r in acl["rules"]}
    assert len({r["id"] for r in acl["rules"]}) == len(acl["rules"])  # no id twice
    assert acl["default_permission"] == "deny"
    for rig in ("r0", "r1", "r2"):
        keys = Keys(rig)
        for key in (keys.flag, keys.interrupt, keys.batch):
            senders = [rid for rid, r in rule_ids.items() if key in r["key_exprs"] and "put" in r["messages"] and r["flows"] == ["ingress"]]
            assert len(senders) == 1, (rig, key)
            subjects = {s for p in acl["policies"] if senders[0] in p["rules"] for s in p["subjects"]}
            assert subjects == {"certificate dsp" if key != keys.batch else "certificate controller"}


def test_the_empty_flag_built_after_the_interrupt_describes_the_block_as_released() -> None:
    """The board takes the flag's fields at the release and builds the message
    after the interrupt is out: a batch admitted in between changes neither
    its expected sequence number nor the flags' numbering."""
    from dsp_service.core import DspCore

    core = DspCore(_settings())
    first = core.admit(_batch(0))
    core.process(_batch(0), first)
    released = core.release_state()
    assert core.admit(_batch(1)).accepted and core.block.full  # the CPU's next batch, before the flag is built
    flag = core.flag_of(released)
    assert (flag.state, flag.next_batch_seq, flag.seq) == ("empty", 1, released.seq)
    assert core.flag("full").seq == released.seq + 1
    eager = DspCore(_settings())
    eager.process(_batch(0), eager.admit(_batch(0)))
    assert eager.release().model_dump(exclude={"wall_time_s"}) == flag.model_dump(exclude={"wall_time_s"})


@pytest.mark.parametrize("value", [0.25, 1.5, -0.3, -0.0, 0.0, 1.0, float("inf"), float("-inf"), np.float64(0.7), np.float64(-2.0)])
def test_the_interrupt_clamps_as_numpy_clip_does(value: float, monkeypatch: pytest.MonkeyPatch) -> None:
    """The interrupt's confidence and valid fraction are clamped with min/max
    (numpy's scalar ufuncs cost ~9 us each on the batch path): the same
    values as ``np.clip`` to the bit, -0.0 included."""
    import dataclasses

    from dsp_service.core import DspCore

    core = DspCore(_settings())
    real_step = core.identifier.step
    monkeypatch.setattr(core.identifier, "step", lambda: dataclasses.replace(real_step(), confidence=value, valid_fraction=value))
    irq = core.process(_batch(0), core.admit(_batch(0)))
    expected = float(np.clip(value, 0.0, 1.0))
    for got in (irq.confidence, irq.valid_fraction):
        assert np.float64(got).tobytes() == np.float64(expected).tobytes()


def test_the_bench_splits_a_batch_round_trip_at_the_interrupts_construction(session: zenoh.Session) -> None:
    """``ralf-hil bench``'s DSP pinger splits each round trip at the
    interrupt's construction (its ``wall_time_s``): the two parts and the
    step add up to the round trip, and the return part is not negative."""
    from workbench.bench.pingers import DspPinger

    settings = _settings()
    with _running_board(session, settings, inline=True):
        pinger = DspPinger(session, settings.rig_id, samples=20)
        try:
            pinger.wait_empty(5.0)
            rtts = [pinger.once() for _ in range(5)]
        finally:
            pinger.close()
    assert len(pinger.out_s) == len(pinger.back_s) == len(pinger.compute_s) == 5
    for rtt, out, back, compute in zip(rtts, pinger.out_s, pinger.back_s, pinger.compute_s):
        assert out + back + compute == pytest.approx(rtt, abs=1e-5)  # one clock (Unix stamps ~1e-7 s apart at 1.7e9 s)
        # the split point lies inside the round trip: the interrupt was built after the batch
        # was sent and its step ran, and before it arrived; the step is part of the round trip
        assert out > -1e-5 and back > -1e-5 and 0 < compute < rtt


def test_health_times_every_interrupt_put_and_the_bench_reads_it_after_a_measurement(session: zenoh.Session) -> None:
    """The board's health carries ``interrupt_put`` (the wall time of each interrupt's put);
    the bench's :class:`HealthWatch` returns the first health message after a given moment."""
    from workbench.bench.pingers import DspPinger, HealthWatch

    settings = _settings()
    with _running_board(session, settings, inline=True) as board:
        watch = HealthWatch(session, board.keys.health("dsp"))
        pinger = DspPinger(session, settings.rig_id, samples=20)
        try:
            pinger.wait_empty(5.0)
            rtts = [pinger.once() for _ in range(5)]
            ended = time.monotonic()
            health = watch.after(ended, timeout_s=5.0)
        finally:
            pinger.close()
            watch.close()
    assert health is not None and health.service == "dsp"
    put = health.latencies["interrupt_put"]
    assert put.count == 5 == health.latencies["batch_to_interrupt"].count
    assert 0 < put.p50 <= put.max and len(rtts) == 5
    assert board.service.put_time.count == 5


@pytest.mark.parametrize("identifier", ["etfe", "etfe-welch", "etfe-transient", "arx"])
def test_the_interrupts_wire_bytes_are_the_models(identifier: str) -> None:
    """The board puts the interrupt's bytes made from its fields by pydantic's
    serializer and validates the model after the put: for every identifier,
    over batches with poles and without, the bytes are those of
    ``encode(Interrupt(**fields))`` and decode to the same interrupt."""
    from dsp_service.core import DspCore
    from protocol.messages import encode_fields

    core = DspCore(_settings(identifier=identifier, fft_width=256))
    rng = np.random.default_rng(7)
    t = np.arange(40 * 20) / 200.0
    drive = rng.standard_normal((2, t.size))
    response = np.vstack([np.convolve(drive[0], np.exp(-t[:60] * 3) * np.sin(2 * np.pi * 6 * t[:60]))[: t.size], drive[1] * 0.5])
    poles_seen = 0
    for seq in range(40):
        sl = slice(seq * 20, (seq + 1) * 20)
        batch = dataclasses.replace(_batch(seq), inputs=drive[:, sl].copy(), outputs=response[:, sl].copy())
        fields = core.process_fields(batch, core.admit(batch))
        core.release()
        model = Interrupt(**fields)
        poles_seen += len(model.poles)
        assert encode_fields(fields) == encode(model)
        assert decode(Interrupt, encode_fields(fields)) == model
    assert poles_seen > 0


@pytest.mark.parametrize("inline", [False, True])
def test_an_interrupt_the_model_refuses_is_an_internal_error_and_the_board_goes_on(
    session: zenoh.Session, monkeypatch: pytest.MonkeyPatch, inline: bool
) -> None:
    """The interrupt is validated after its put: a field the model refuses (a
    board bug, here a confidence of 2) is counted as an internal error, the
    block is released with an empty flag, and the next batch is answered."""
    from dsp_service.core import DspCore

    original = DspCore.process_fields

    def process_fields(core: DspCore, batch: SampleBatch, admission: object) -> dict[str, object]:
        fields = original(core, batch, admission)  # type: ignore[arg-type]
        return {**fields, "confidence": 2.0} if batch.seq == 0 else fields

    monkeypatch.setattr(DspCore, "process_fields", process_fields)
    keys = Keys(_settings().rig_id)
    raw: queue.Queue[bytes] = queue.Queue()
    sub = session.declare_subscriber(keys.interrupt, lambda s: raw.put(s.payload.to_bytes()))
    try:
        with _running_board(session, _settings(rig_id=keys.rig_id), publisher=True, inline=inline) as board:
            assert board.probe.next("flag", timeout=10.0).state == "empty"  # type: ignore[attr-defined]
            assert board.pub is not None
            board.pub.put(encode_batch(_batch(0)))
            with pytest.raises(ProtocolError, match="confidence"):
                decode(Interrupt, raw.get(timeout=5.0))  # what a controller would refuse (and count)
            flag = board.probe.next("flag")
            assert flag.state == "empty" and flag.next_batch_seq == 1  # type: ignore[attr-defined]
            assert board.service.core.block.counters.internal_errors == 1
            board.pub.put(encode_batch(_batch(0)))  # the CPU resends it: the refused bytes are not sent again
            with pytest.raises(queue.Empty):
                raw.get(timeout=0.5)
            board.pub.put(encode_batch(_batch(1)))
            irq = board.probe.next("irq")
            assert isinstance(irq, Interrupt) and irq.batch_seq == 1
    finally:
        sub.undeclare()


def test_the_service_loads_its_regime_bank_file_at_start_and_writes_it_at_close(session: zenoh.Session, tmp_path: Path) -> None:
    """``RALF_ARX_REGIME_BANK_FILE`` on the service: a bank file there is in the identifier before the first
    batch, and close() writes what the identifier holds then (no temporary file left)."""
    from dsp_service.arx_regime_bank import load_regime_bank, save_regime_bank

    from .test_arx_regime_bank import _learned_bank

    _cfg, state = _learned_bank()
    path = tmp_path / "bank.npz"
    save_regime_bank(path, state)
    before = path.stat().st_mtime_ns
    settings = _settings(fft_width=2048, identifier="arx", arx_regime_bank=4, arx_regime_bank_file=str(path))
    service = DspService(settings, session)
    try:
        arx = service.identifier.arx
        assert arx is not None and len(arx.bank) == 2
        assert service.process_batch(_batch(0)) is not None
    finally:
        time.sleep(0.01)
        service.close()
    assert path.stat().st_mtime_ns > before and [p.name for p in tmp_path.iterdir()] == ["bank.npz"]
    written = load_regime_bank(path)
    held = arx.bank_state()
    assert written.regimes == 2 and all(np.array_equal(getattr(written, k), getattr(held, k)) for k in ("scale", "R", "theta", "residual_power"))


def test_tf_queries_over_the_rate_are_refused_and_counted(session: zenoh.Session) -> None:
    """A flood of TF queries (any tool may query): the burst is answered, the
    rest get a short error at once and are counted in the DSP's health. The
    gate's clock stands still here, so the count does not depend on speed."""
    from service_kit.query_gate import OVER_RATE, QUERY_LIMITS, QueryGate

    settings = _settings()
    service = DspService(settings, session)
    limit = QUERY_LIMITS["tf"]
    service._tf_gate = QueryGate("tf", limit, clock=lambda: 100.0)  # noqa: SLF001
    try:
        service.process_batch(_batch(0, rng=np.random.default_rng(7)))
        ok = errors = 0
        for _ in range(limit.burst + 5):
            for reply in session.get(Keys(settings.rig_id).tf, timeout=5.0):
                if reply.ok is not None:
                    ok += 1
                else:
                    assert reply.err is not None and reply.err.payload.to_bytes() == OVER_RATE
                    errors += 1
        counters = service._build_health(0).counters  # noqa: SLF001
    finally:
        service.close()
    assert (ok, errors) == (limit.burst, 5)
    assert counters["q_tf_answered"] == limit.burst and counters["q_tf_dropped_rate"] == 5 and counters["q_tf_failed"] == 0
