"""Attacks on the controller's zenoh inputs during a run (in-process rig,
lockstep so the record is deterministic): a 10 MB interrupt and a flood of
5000 interrupts are dropped and counted, and the run's record equals an
undisturbed run's, so nothing of them reached the control."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import zenoh

from controller.record import load_record
from protocol.keys import Keys
from protocol.messages import Interrupt, encode
from rig.composition import run_in_process

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

    timer = threading.Timer(0.5, attack_now) if attack else None
    try:
        if timer:
            timer.start()
        run = run_in_process(controller={"duration_s": 6.0, "tf_download_samples": 0, "record": str(record), "oatf_mode": "adaptive"}, dsp={"fft_width": 256}, common={"rig_id": rig_id}, session=session)
        run.controller.save(str(record), run.result)
    finally:
        if timer:
            timer.join()
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
