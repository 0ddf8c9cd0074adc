"""The direct co-simulation (workbench.cosim): one thread, frames through the CAN
codecs, the DSP's latency applied in simulated ticks; and the scheduler
implementations it stands on."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from controller.record import load_record
from dsp_service.core import DspCore
from protocol.errors import ConfigError
from protocol.messages import ConfigChange
from protocol.settings import DspSettings
from service_kit.clock import LockstepScheduler, RealTimeScheduler, SimulatedScheduler
from workbench.cosim import run_cosim


def test_cosim_runs_every_board_in_this_thread_through_the_codecs(monkeypatch: pytest.MonkeyPatch) -> None:
    # no thread is started by the run: counted at Thread.start, not by the live thread count, which a thread
    # of an earlier test (a pool, a logging or zenoh thread) ending or starting meanwhile changes too
    started: list[threading.Thread] = []
    start = threading.Thread.start

    def counting_start(thread: threading.Thread) -> None:
        if threading.current_thread() is this:
            started.append(thread)
        start(thread)

    this = threading.current_thread()
    monkeypatch.setattr(threading.Thread, "start", counting_start)
    run = run_cosim(controller={"duration_s": 3.0, "tf_download_samples": 200, "batch_size": 20}, dsp={"fft_width": 256, "emulated_latency_s": 0.05})
    monkeypatch.undo()
    assert started == []
    r = run.result
    assert r.error is None and r.ticks == 600
    c = r.counters
    # every tick: one SYNC frame to the node, one TPDO1 back (decoded from 12-bit words), one RPDO1
    assert c["syncs_sent"] == c["tpdos"] == 600 and c["rpdos_sent"] >= 600
    assert run.node.counters.as_dict()["tx_tpdo1"] == 600 and run.plant.syncs == 600
    assert c["interrupts"] == c["interrupts_applied"] >= c["batches_sent"] - 1 >= 25  # the last may still be in flight
    assert c["deadline_misses"] == 0 and c["sync_retries"] == 0
    assert run.dsp.block.counters.batches_accepted == c["batches_sent"]
    assert c["tf_downloads"] == 2  # at ticks 200 and 400, while no batch was in flight
    # heartbeats ran on the simulated clock: one per 100 ms of the run
    assert 25 <= c["heartbeats"] <= 35
    assert run.plant.arm.time_s == pytest.approx(3.0, abs=1e-9)


def test_cosim_applies_each_interrupt_at_its_due_tick(tmp_path) -> None:
    """Batch l = 20 at 200 Hz, latency 0.05 s = 10 ticks: each interrupt lands
    10 ticks after its batch went out, never earlier, never later."""
    run = run_cosim(controller={"duration_s": 2.0, "tf_download_samples": 0, "batch_size": 20}, dsp={"fft_width": 256, "emulated_latency_s": 0.05})
    path = tmp_path / "rec"
    run.controller.save(str(path), run.result)
    rec = load_record(path)
    applied = np.flatnonzero(rec["irq_applied"] > 0)
    assert applied.size >= 10
    # batch k goes out when its 20th sample is in (tick 19 + 20 k: the latency is shorter
    # than the batch period, so samples gathered while a batch is in flight go in the next)
    sent = 19 + 20 * np.arange(applied.size)
    assert np.array_equal(applied, sent + 10)


def test_cosim_pairs_with_its_board_and_refuses_any_other_at_the_edge() -> None:
    """The direct port goes through the same inbox as zenoh: the controller
    pairs with the core's board id after its reset; an interrupt or flag with
    another board id, or an interrupt for no batch sent, is refused."""
    from protocol.messages import BlockFlag, Interrupt, encode

    run = run_cosim(controller={"duration_s": 1.0, "tf_download_samples": 0, "batch_size": 20}, dsp={"fft_width": 256, "emulated_latency_s": 0.05})
    ctrl = run.controller
    inbox = ctrl.dsp.inbox
    assert inbox.paired_board == ctrl.port.board_id  # type: ignore[attr-defined]
    assert run.result.counters.get("in_interrupt_refused", 0) == 0
    assert run.result.counters["interrupts_applied"] > 0
    before = inbox.events.counters("interrupt").refused
    left = len(inbox.events)  # the answers to the last batch, never taken
    irq = encode(Interrupt(seq=0, sim_time_s=0.0, batch_seq=0, confidence=1.0, compute_time_s=0.0))
    inbox.on_port_event("interrupt", irq, 0.0, b"another-board")
    inbox.on_port_event("interrupt", irq, 0.0, None)
    unsent = encode(Interrupt(seq=0, sim_time_s=0.0, batch_seq=10**9, confidence=1.0, compute_time_s=0.0))
    inbox.on_port_event("interrupt", unsent, 0.0, inbox.paired_board)
    assert inbox.events.counters("interrupt").refused == before + 3
    flag = encode(BlockFlag(seq=0, sim_time_s=0.0, state="empty", next_batch_seq=0, fft_width=256, batch_size=20))
    flags_refused = inbox.events.counters("flag").refused
    inbox.on_port_event("flag", flag, 0.0, b"another-board")
    assert inbox.events.counters("flag").refused == flags_refused + 1
    assert len(inbox.events) == left  # nothing of it was queued
    inbox.on_port_event("interrupt", b"x" * 100_000, 0.0, inbox.paired_board)
    assert inbox.events.counters("interrupt").oversize == 1


def test_cosim_settings_errors_name_the_service_and_variable() -> None:
    with pytest.raises(ConfigError, match="(?s)controller: .*RALF_OATF_MODE"):
        run_cosim(controller={"duration_s": 1.0, "oatf_mode": "sideways"})


def test_dsp_core_refuses_an_emulated_latency_beyond_its_bound() -> None:
    core = DspCore(DspSettings(fft_width=256, emulated_latency_s=0.1))
    with pytest.raises(ValueError, match="emulated_latency_s"):
        core.apply_config(ConfigChange(seq=0, sim_time_s=0.0, emulated_latency_s=1e6))
    assert core.emulated_latency_s == 0.1


def test_schedulers() -> None:
    sim = SimulatedScheduler()
    assert sim.wait_until(2.5) and sim.now() == 2.5
    assert sim.wait_until(1.0) and sim.now() == 2.5  # never back
    sim.wait(0.5)
    assert sim.now() == 3.0
    sim.stop.set()
    assert not sim.wait(1.0) and sim.stopping
    stop = threading.Event()
    lock = LockstepScheduler(stop)
    t = lock.now()
    assert lock.wait_until(t + 3600.0)  # lockstep never paces: returns at once
    real = RealTimeScheduler(stop)
    stop.set()
    assert not real.wait(3600.0)  # a stop ends a real-time wait at once


def test_a_real_time_wait_ends_at_its_deadline_and_a_later_stop_ends_it_early() -> None:

    from service_kit.clock import SLEEP_SLICE_S

    stop = threading.Event()
    real = RealTimeScheduler(stop)
    for span in (0.2 * SLEEP_SLICE_S, 3 * SLEEP_SLICE_S):  # only the final sleep; the event, then the sleep
        deadline = real.now() + span
        assert real.wait_until(deadline)
        assert real.now() >= deadline  # never early
    timer = threading.Timer(0.05, stop.set)
    timer.start()
    started = real.now()
    assert not real.wait(600.0)  # a stop while waiting ends the wait (within a slice), reported as stopping
    assert real.now() - started < 300.0
    timer.join()


def test_the_empty_flag_after_an_interrupt_is_not_a_late_flag() -> None:
    """The DSP raises the interrupt, then flags the release: when the CPU's
    next batch went out in between, that flag is the interrupt's echo, not
    late; a flag for an earlier release still is."""
    from controller.dsp_link import SentBatch
    from protocol.messages import BlockFlag, Interrupt

    run = run_cosim(controller={"duration_s": 0.5, "tf_download_samples": 0, "batch_size": 20}, dsp={"fft_width": 256, "emulated_latency_s": 0.0})
    ctrl, link = run.controller, run.controller.link
    k = link.next_seq
    ctrl.dsp.latest_interrupt = Interrupt(seq=0, sim_time_s=0.0, batch_seq=k, confidence=1.0, compute_time_s=0.0)
    link.in_flight = SentBatch(seq=k + 1, tick=0, sim_time_s=0.0, due_tick=0, deadline_tick=1)
    link.next_seq = k + 2
    late = link.counters.flags_late

    def flag(next_seq: int) -> BlockFlag:
        return BlockFlag(seq=0, sim_time_s=0.0, state="empty", next_batch_seq=next_seq, fft_width=256, batch_size=20)

    ctrl.dsp.take_event("flag", flag(k + 1), 0.0)
    assert link.counters.flags_late == late and link.in_flight is not None
    ctrl.dsp.latest_interrupt = Interrupt(seq=0, sim_time_s=0.0, batch_seq=k - 1, confidence=1.0, compute_time_s=0.0)
    ctrl.dsp.take_event("flag", flag(k + 1), 0.0)
    assert link.counters.flags_late == late + 1
