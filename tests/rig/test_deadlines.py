"""Deadline behaviour, tested deterministically by injecting faults: a slowed
DSP, a DSP killed and restarted, a stalled controller, SYNC frames lost on
the bus. Margins are wide (an injected delay of several deadlines), so the
outcome does not depend on the machine's load."""

from __future__ import annotations

import json
import signal
import time
import uuid
from pathlib import Path

import pytest

from protocol.can_map import EmcyCode
from workbench.composition import run_in_process
from workbench.cosim import run_cosim
from workbench.launcher import RigObserver, RigPlan, start_service, stop_service

SLOW_BOARD = json.dumps({"dsp_delay_s": 0.35})
"""The DSP board takes 350 ms longer per batch."""
STALL = json.dumps({"stalls": [{"at_s": 1.0, "wall_s": 0.4}]})
"""The controller's loop freezes 0.4 s (wall clock) before the tick at 1 s."""
EVERY_50TH_SYNC = json.dumps({"faults": [{"link": "can", "kinds": ["sync"], "start_s": 0.2425, "outage": {"every_s": 0.25, "length_s": 0.005}}]})
"""SYNC lost at ticks 49, 99, 149, ... (200 Hz): an outage of one period every 50, centred on the tick."""


@pytest.mark.timeout(120)
def test_slowed_dsp_misses_are_counted_and_no_sample_is_lost() -> None:
    """A DSP that answers 350 ms late (beyond the 150 ms batch period) and
    overruns its compute budget, co-simulated (the miss is a due time in
    simulated ticks, so the outcome does not depend on the host's load; the
    real-time reaction is covered by the policy-stop test below)."""
    run = run_cosim(
        controller={"duration_s": 4.0, "policies": "deadline=degrade", "oatf_mode": "adaptive", "tf_download_samples": 0},
        dsp={"emulated_latency_s": 0.35, "fault_scenario": SLOW_BOARD, "fft_width": 256},
    )
    ctrl = run.controller
    counters = run.result.counters
    # the loop kept its rate: every tick of the 4 s ran (no plant fault, no stop)
    assert run.result.error is None and run.result.ticks == 800
    assert counters["deadline_misses"] >= 3
    assert ctrl.monitors.episodes["deadline"] >= 3
    # batches grew while the board was busy: samples waited, none dropped
    assert counters["samples_dropped"] == 0
    assert ctrl.link.counters.samples_sent / ctrl.link.counters.batches_sent > 30  # more than the batch size each
    dsp = run.dsp.block.counters
    assert dsp.budget_misses >= 3 and dsp.samples_missing == 0 and dsp.sequence_gaps == 0
    assert ctrl.link.counters.samples_sent + ctrl.link.pending == run.result.ticks  # every sample sent or still waiting
    assert dsp.samples_accepted <= ctrl.link.counters.samples_sent
    assert run.health["dsp"].counters["budget_misses"] >= 3


@pytest.mark.timeout(120)
def test_dsp_deadline_policy_stop_ends_the_run_with_a_clear_error() -> None:
    run = run_in_process(
        controller={"duration_s": 4.0, "policies": "deadline=stop", "tf_download_samples": 0},
        dsp={"fault_scenario": SLOW_BOARD, "fft_width": 256, "emulated_latency_s": 0.0},
        common={"clock": "realtime"},
    )
    assert run.result.error is not None and "deadline" in run.result.error
    assert run.result.ticks < 800


@pytest.mark.timeout(120)
def test_controller_stall_trips_the_plant_watchdog_which_holds_valves_and_sends_emcy() -> None:
    run = run_in_process(
        controller={"duration_s": 2.0, "fault_scenario": STALL, "timeouts": "plant_heartbeat_s=5", "tf_download_samples": 0},
        plant={"watchdog_periods": 5},
        common={"clock": "realtime"},
    )
    codes = [e.code for e in run.controller.plant.emergencies]
    assert EmcyCode.SYNC_TIMEOUT in codes
    assert 0x0000 in codes[codes.index(EmcyCode.SYNC_TIMEOUT) :]  # cleared when SYNC came back
    plant = run.health["plant"].counters
    assert plant["watchdog_trips"] >= 1 and plant["watchdog_recoveries"] == plant["watchdog_trips"]  # a loaded host may add a trip
    assert run.result.error is None and run.result.ticks == 400


@pytest.mark.timeout(120)
def test_sync_frames_lost_on_the_bus_are_seen_as_counter_gaps() -> None:
    run = run_in_process(controller={"duration_s": 2.0, "fault_scenario": EVERY_50TH_SYNC, "tf_download_samples": 0})
    assert run.result.error is None and run.result.ticks == 400
    assert run.result.counters["syncs_dropped"] == 8  # ticks 49, 99, ..., 399
    assert run.result.counters["sync_retries"] == 0  # the controller knows no TPDO1 answers a lost SYNC
    # the node sees each gap at the next SYNC: the one after tick 399 is past the run's end
    assert run.health["plant"].counters["sync_gaps"] == 7


@pytest.mark.timeout(400)
def test_dsp_killed_mid_run_is_detected_control_continues_and_it_is_picked_up_again(tmp_path: Path) -> None:
    plan = RigPlan.local(
        rig_id=f"kill-{uuid.uuid4().hex[:6]}",
        overrides={"dsp": {"RALF_FFT_WIDTH": "256"}, "controller": {"RALF_OATF_MODE": "adaptive", "RALF_TIMEOUTS": "plant_heartbeat_s=20"}},
    )
    observer = RigObserver(plan)
    procs = {name: start_service(plan, name, tmp_path) for name in ("dsp", "plant", "controller")}
    try:
        # The waits are bounds for a loaded host, not figures: what is tested is that each
        # event is noticed and the run goes on, not how fast (that is the bench's). The
        # plant's heartbeat may go quiet for a second or more at load 15 (the review saw
        # that end the run): the subject here is the DSP, so the controller tolerates 20 s.
        def wait_for(cond, timeout: float = 60.0) -> None:  # type: ignore[no-untyped-def]
            deadline = time.monotonic() + timeout
            while not cond():
                assert time.monotonic() < deadline, {n: p.log_path.read_text()[-1500:] for n, p in procs.items()}
                time.sleep(0.05)

        wait_for(lambda: observer.status is not None and observer.status.interrupts >= 10)
        procs["dsp"].popen.send_signal(signal.SIGKILL)
        procs["dsp"].popen.wait()
        wait_for(lambda: observer.health.get("controller") is not None and observer.health["controller"].counters.get("dsp_lost", 0) >= 1, 30)
        ticks_at_loss = observer.status.ticks  # type: ignore[union-attr]
        wait_for(lambda: observer.status.ticks > ticks_at_loss + 200, 30)  # type: ignore[union-attr]
        irq_before = observer.status.interrupts  # type: ignore[union-attr]
        procs["dsp"] = start_service(plan, "dsp", tmp_path / "restart")
        wait_for(lambda: observer.status.interrupts >= irq_before + 10)  # type: ignore[union-attr]
        counters = observer.health["controller"].counters
        assert counters["dsp_found"] >= 2 and counters["dsp_lost"] == 1
        assert counters["episodes_dsp_lost"] == 1  # the policy (degrade: fallback OATF design) was applied once
        # a frozen DSP (SIGSTOP) is noticed too, within the zenoh lease (RALF_ZENOH_LEASE_MS)
        procs["dsp"].popen.send_signal(signal.SIGSTOP)
        try:
            wait_for(lambda: observer.health["controller"].counters.get("dsp_lost", 0) >= 2, 60)
        finally:
            procs["dsp"].popen.send_signal(signal.SIGCONT)
        wait_for(lambda: observer.health["controller"].counters.get("dsp_found", 0) >= 3, 60)  # generous: a loaded host reconnects slowly
    finally:
        codes = {name: stop_service(procs[name]) for name in ("controller", "plant", "dsp")}
        observer.close()
    assert codes == {"controller": 0, "plant": 0, "dsp": 0}


@pytest.mark.timeout(60)
def test_the_controller_sets_the_plant_sample_period_by_sdo() -> None:
    """Plant configured for 100 Hz, controller for 200 Hz: the master's SDO
    write of 0x2000 wins, so each lockstep SYNC advances the arm 5 ms."""
    run = run_in_process(controller={"duration_s": 1.0, "tf_download_samples": 0}, plant={"sample_rate_hz": 100.0})
    assert run.result.error is None and run.result.ticks == 200
    assert run.health["plant"].counters["sdo_downloads"] == 2  # 0x2000, then RPDO1's event timer (0x1400 sub 5)
    truth_time = run.health["plant"].sim_time_s
    assert truth_time == pytest.approx(1.0, abs=1e-9)
