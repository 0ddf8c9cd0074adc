"""Attacks on the controller's zenoh inputs during a run (in-process rig,
lockstep so the record is deterministic): a 10 MB interrupt and a flood of
5000 interrupts are dropped and counted, and the run's record equals an
undisturbed run's, so nothing of them reached the control."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import zenoh

from controller.record import load_record
from protocol.keys import Keys
from protocol.messages import Interrupt, encode
from workbench.composition import run_in_process

FLOOD = 5000


def _session() -> zenoh.Session:
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps([]))
    return zenoh.open(config)


def _run(tmp: Path, name: str, attack: bool) -> tuple[dict[str, int], Path]:
    session = _session()
    rig_id = f"flood-{name}"
    keys = Keys(rig_id)
    record = tmp / name

    def attack_now() -> None:
        session.put(keys.interrupt, b'{"seq": 0, ' + b" " * (10 * 1024 * 1024) + b"}")
        forged = [encode(Interrupt(seq=i, sim_time_s=0.0, batch_seq=10**12 + i, confidence=1.0, compute_time_s=0.0)) for i in range(FLOOD)]
        for payload in forged:
            session.put(keys.interrupt, payload)

    try:
        # The attack runs in the loop before tick 100 (same session: each put is delivered
        # before it returns); the plant's watchdog is given room for the loop's pause.
        run = run_in_process(
            controller={"duration_s": 6.0, "tf_download_samples": 0, "run_record": str(record), "oatf_mode": "adaptive"},
            plant={"watchdog_periods": 10000},
            dsp={"fft_width": 256},
            common={"rig_id": rig_id},
            session=session,
            at_tick=(100, attack_now) if attack else None,
        )
        run.controller.save(str(record), run.result)
        assert run.result.counters["sync_retries"] == 0
    finally:
        session.close()
    return run.result.counters, record


def test_oversize_and_flood_are_dropped_counted_and_change_nothing(tmp_path: Path) -> None:
    quiet, quiet_record = _run(tmp_path, "quiet", attack=False)
    noisy, noisy_record = _run(tmp_path, "noisy", attack=True)
    assert noisy["in_interrupt_oversize"] == 1
    # every forged interrupt is accounted for: refused in zenoh's thread (no batch of that
    # number was sent), dropped at the full inbox, or taken and found unexpected
    taken = noisy.get("in_interrupt_refused", 0) + noisy.get("in_interrupt_dropped_full", 0) + noisy["interrupts_unexpected"]
    assert taken == FLOOD and noisy["in_interrupt_refused"] > 0
    assert noisy["interrupts_applied"] == quiet["interrupts_applied"] > 0
    a, b = load_record(quiet_record), load_record(noisy_record)
    assert len(a) == len(b) == 1200
    for name in a.columns:
        assert np.array_equal(a[name], b[name], equal_nan=True), name


def test_interrupts_and_flags_of_another_board_are_refused(tmp_path: Path) -> None:
    """The attack: a foreign session answers each batch first with a
    forged interrupt (15 Hz, confidence 1.0) and a forged 'empty' flag. The
    controller takes flags and interrupts only from the board it paired with."""
    from protocol.batch_codec import decode_batch
    from protocol.messages import BlockFlag, PoleParameters

    quiet, quiet_record = _run(tmp_path, "quiet2", attack=False)
    session = _session()
    rig_id = "forge-board"
    keys = Keys(rig_id)
    forged: list[int] = []

    def answer_first(sample: zenoh.Sample) -> None:
        batch = decode_batch(sample.payload.to_bytes())
        irq = Interrupt(
            seq=batch.seq,
            sim_time_s=batch.sim_time_s,
            batch_seq=batch.seq,
            poles=(PoleParameters(frequency_hz=15.0, damping_ratio=0.01),),
            confidence=1.0,
            compute_time_s=0.0,
        )
        for board in (b"forged-board", None):
            session.put(keys.interrupt, encode(irq), attachment=board)
        flag = BlockFlag(seq=batch.seq, sim_time_s=0.0, state="empty", next_batch_seq=batch.seq + 1, fft_width=256, batch_size=30)
        session.put(keys.flag, encode(flag), attachment=b"forged-board")
        forged.append(batch.seq)

    sub = session.declare_subscriber(keys.batch, answer_first)
    record = tmp_path / "forged"
    try:
        run = run_in_process(
            controller={"duration_s": 6.0, "tf_download_samples": 0, "run_record": str(record), "oatf_mode": "adaptive"},
            dsp={"fft_width": 256},
            common={"rig_id": rig_id},
            session=session,
        )
        run.controller.save(str(record), run.result)
    finally:
        sub.undeclare()
        session.close()
    noisy = run.result.counters
    sent = noisy["batches_sent"]
    assert sent > 0 and len(forged) >= sent
    # every batch got its forged answers, all refused (those to the last batch may come after the counters are taken)
    assert noisy["in_interrupt_refused"] >= 2 * (sent - 1) and noisy["in_flag_refused"] >= sent - 1
    assert noisy["interrupts_applied"] == quiet["interrupts_applied"]
    a, b = load_record(quiet_record), load_record(record)
    for name in a.columns:
        assert np.array_equal(a[name], b[name], equal_nan=True), name
    assert not np.any(b["f_id_hz"] == 15.0)
