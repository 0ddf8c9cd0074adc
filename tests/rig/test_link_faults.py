"""Link faults as scripted stimulus: the pure engine against scipy's
distributions and tests, and the controller's reaction to each fault kind
in the co-simulation (deterministic, bit-for-bit reproducible)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy import stats

from controller.plant_link import PlantLink
from controller.service import ControllerService
from dsp_service.core import DspCore
from plant_emulator.node import CanopenNode
from plant_emulator.service import PlantApplication, node_config
from service_kit.clock import SimulatedScheduler
from service_kit.link_faults import FaultEngine, Jitter, ScenarioError, load_scenario, parse_scenario, uniform
from workbench.cosim import DirectCanWire, DirectDspPort, run_cosim, settings_for

DOCS = Path(__file__).resolve().parents[2] / "docs" / "scenarios"
FAST = {"tf_download_samples": 0, "batch_size": 20}
FAST_DSP = {"fft_width": 256, "emulated_latency_s": 0.05}


def scenario(*faults: dict[str, Any], seed: int = 0) -> str:
    return json.dumps({"seed": seed, "faults": list(faults)})


# -- the engine --------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "jitter, reference",
    [
        (Jitter(distribution="exponential", scale_s=0.002), stats.expon(scale=0.002)),
        (Jitter(distribution="uniform", low_s=0.001, high_s=0.003), stats.uniform(loc=0.001, scale=0.002)),
        (Jitter(distribution="normal", mean_s=0.01, std_s=0.001), stats.norm(loc=0.01, scale=0.001)),
    ],
)
def test_jitter_draws_follow_their_distribution(jitter: Jitter, reference: Any) -> None:
    engine = FaultEngine(parse_scenario(scenario({"link": "zenoh", "kinds": ["batch"], "jitter": jitter.model_dump()}, seed=11)))
    delays = np.array([engine.decide("batch", seq, 0.0, 0.0).delay_s for seq in range(4000)])
    assert stats.kstest(delays, reference.cdf).pvalue > 1e-3


def test_drop_and_duplicate_rates_are_binomial_and_independent_of_call_order() -> None:
    text = scenario({"link": "can", "kinds": ["rpdo", "tpdo"], "drop": 0.1, "duplicate": 0.3}, seed=5)
    engine = FaultEngine(parse_scenario(text))
    fates = [engine.decide("rpdo", k, k * 0.005, 0.0) for k in range(5000)]
    dropped = sum(f.dropped for f in fates)
    assert stats.binomtest(dropped, 5000, 0.1).pvalue > 1e-3
    kept = [f for f in fates if not f.dropped]
    assert stats.binomtest(sum(f.copies == 2 for f in kept), len(kept), 0.3).pvalue > 1e-3
    # pure: the same messages in reverse order, interleaved with another kind, get the same fates
    other = FaultEngine(parse_scenario(text))
    backwards = {}
    for k in reversed(range(5000)):
        other.decide("tpdo", k, 0.0, 0.0)
        backwards[k] = other.decide("rpdo", k, k * 0.005, 0.0)
    assert all(backwards[k] == fates[k] for k in range(5000))
    assert engine.counters.dropped["rpdo"] == dropped
    # a different seed, different fates
    assert uniform(5, 0, 3, 1, 1) != uniform(6, 0, 3, 1, 1)


def test_windows_and_burst_outages() -> None:
    engine = FaultEngine(
        parse_scenario(scenario({"link": "zenoh", "kinds": ["interrupt"], "start_s": 1.0, "stop_s": 3.0, "outage": {"every_s": 1.0, "length_s": 0.25}}))
    )
    t = np.arange(0.0, 4.0, 0.05)
    dropped = np.array([engine.decide("interrupt", i, float(x), 0.0).dropped for i, x in enumerate(t)])
    expected = (t >= 1.0) & (t < 3.0) & (((t - 1.0) % 1.0) < 0.25)
    assert np.array_equal(dropped, expected)
    assert not engine.covers("batch") and engine.decide("batch", 0, 2.0, 0.0).dropped is False


def test_scenarios_are_validated_and_the_examples_load() -> None:
    with pytest.raises(ScenarioError, match="unknown kinds"):
        parse_scenario(scenario({"link": "can", "kinds": ["interrupt"]}))
    with pytest.raises(ScenarioError, match="stop_s"):
        parse_scenario(scenario({"link": "can", "kinds": ["sync"], "start_s": 2, "stop_s": 1}))
    with pytest.raises(ScenarioError):
        parse_scenario("faults: [{link: serial, kinds: [x]}]")
    for path in sorted(DOCS.glob("*")):
        s = load_scenario(path)
        assert s.faults and s.name == path.stem


# -- the controller's reaction, in the co-simulation -------------------------------------------
def _cosim(faults: str, **controller: Any) -> Any:
    return run_cosim(controller={"duration_s": 4.0, **FAST, "fault_scenario": faults, **controller}, dsp=dict(FAST_DSP))


def _columns(run: Any) -> dict[str, np.ndarray]:
    return {k: np.asarray(v) for k, v in run.controller.record.to_columns().items()}


def _same(a: Any, b: Any) -> None:
    ca, cb = _columns(a), _columns(b)
    assert ca.keys() == cb.keys()
    for k in ca:
        assert np.array_equal(ca[k], cb[k], equal_nan=True), k


def test_interrupt_outage_fires_the_deadline_monitor_and_the_run_reproduces_bit_for_bit() -> None:
    faults = scenario({"link": "zenoh", "kinds": ["interrupt"], "start_s": 1.0, "stop_s": 2.0, "drop": 1.0})
    a = _cosim(faults)
    c = a.result.counters
    # batches every 100 ms; the 10 whose interrupts are due in [1, 2) s are lost at their due tick
    assert c["fault_dropped_interrupt"] == 10 == c["interrupts_lost"]
    assert a.controller.monitors.episodes["deadline"] == 10
    assert "lost at its due tick" in (a.controller.monitors.last or "") or "deadline" in (a.controller.monitors.last or "")
    assert c["interrupts_applied"] == c["batches_sent"] - 10 - 1  # the last one still in flight
    _same(a, _cosim(faults))
    clean = run_cosim(controller={"duration_s": 4.0, **FAST}, dsp=dict(FAST_DSP))
    applied, clean_applied = _columns(a)["irq_applied"], _columns(clean)["irq_applied"]
    assert not np.array_equal(applied, clean_applied)
    assert np.array_equal(applied[:200], clean_applied[:200])  # nothing changes before the fault


def test_batch_loss_restarts_the_dsp_history_and_identification_resumes() -> None:
    a = _cosim(scenario({"link": "zenoh", "kinds": ["batch"], "start_s": 1.0, "stop_s": 1.3, "drop": 1.0}))
    c = a.result.counters
    assert c["fault_dropped_batch"] >= 1 and c["interrupts_lost"] == c["fault_dropped_batch"]
    assert a.dsp.block.counters.samples_missing > 0  # the next batch said its samples were missing
    applied = np.flatnonzero(_columns(a)["irq_applied"] > 0)
    assert applied[-1] > 700  # interrupts came back after the outage
    assert "dropped on zenoh" in (a.controller.last_miss or "") or a.controller.monitors.episodes["deadline"] >= 1


def test_interrupts_delayed_past_the_deadline_are_misses_that_name_the_fault() -> None:
    a = _cosim(scenario({"link": "zenoh", "kinds": ["interrupt"], "start_s": 1.0, "stop_s": 2.0, "delay_s": 0.08}), policies="deadline=degrade")
    c = a.result.counters
    # deadline = batch period 100 ms; latency 50 ms + 80 ms delay = 130 ms: a miss, not a loss
    assert c["deadline_misses"] >= 5 and c["interrupts_lost"] == 0
    assert c["fault_delayed_interrupt"] == c["deadline_misses"]
    assert "link fault: interrupt delayed 80.0 ms" in (a.controller.monitors.last or "")
    applied = np.flatnonzero(_columns(a)["irq_applied"] > 0)
    late = applied[(applied > 200) & (applied < 400)]
    assert np.all(np.diff(late) >= 20)  # still one per batch, each 16 ticks later


def test_tpdo_loss_holds_the_last_sample_and_rpdo_loss_the_last_command() -> None:
    a = _cosim(
        scenario(
            {"link": "can", "kinds": ["tpdo"], "start_s": 1.0, "stop_s": 1.05, "drop": 1.0},
            {"link": "can", "kinds": ["rpdo"], "start_s": 2.0, "stop_s": 2.05, "drop": 1.0},
        )
    )
    col = _columns(a)
    held = col["ai1_word"][200:210]
    assert np.all(held == col["ai1_word"][199])  # ticks 200..209 have no sample: the last one held
    assert a.result.counters["fault_dropped_tpdo"] == 10 and a.result.counters["fault_dropped_rpdo"] == 10
    assert a.result.error is None and a.result.ticks == 800


def _cosim_with_watchdog(faults: str, duration_s: float = 2.0) -> tuple[Any, PlantApplication, CanopenNode]:
    """The co-simulation with the plant's SYNC watchdog on (as on the real rig;
    a lockstep plant turns it off), on the simulated clock."""
    cs, ps, ds = settings_for({"duration_s": duration_s, **FAST, "fault_scenario": faults}, None, dict(FAST_DSP))
    scheduler = SimulatedScheduler()
    app = PlantApplication(ps, clock=scheduler.now)
    node = CanopenNode(app, dataclasses.replace(node_config(ps), watchdog_periods=5))
    link = PlantLink(DirectCanWire(node, scheduler), cs.node_id, clock=scheduler.now)  # type: ignore[arg-type]
    ctrl = ControllerService(cs, None, link, port=DirectDspPort(DspCore(ds)), scheduler=scheduler, keep_record=True)
    try:
        result = ctrl.run(scheduler.stop)
    finally:
        ctrl.close()
    return result, app, node


def test_sync_outage_trips_the_plant_watchdog_which_holds_the_valves_then_releases() -> None:
    faults = scenario({"link": "can", "kinds": ["sync"], "start_s": 1.0, "stop_s": 1.2, "drop": 1.0})
    result, app, node = _cosim_with_watchdog(faults)
    n = node.counters.as_dict()
    assert n["watchdog_trips"] == 1 and n["watchdog_recoveries"] == 1
    assert result.counters["fault_dropped_sync"] == 40 and result.error is None
    again, _, node2 = _cosim_with_watchdog(faults)
    assert again.counters == result.counters and node2.counters.as_dict() == n


def test_rpdo_outage_trips_the_watchdog_while_sync_keeps_coming() -> None:
    result, app, node = _cosim_with_watchdog(scenario({"link": "can", "kinds": ["rpdo"], "start_s": 1.0, "stop_s": 1.2, "drop": 1.0}))
    n = node.counters.as_dict()
    assert n["rpdo_timeouts"] == n["watchdog_trips"] == 1 and n["watchdog_recoveries"] == 1
    assert result.counters["fault_dropped_rpdo"] == 40


def test_a_faulted_cosim_equals_the_faulted_one_process_lockstep_run() -> None:
    """The same scenario in the co-simulation and in lockstep over the virtual
    CAN bus and a zenoh session with the real DSP service: the same record."""
    from workbench.composition import run_in_process

    faults = scenario(
        {"link": "zenoh", "kinds": ["interrupt"], "start_s": 1.0, "stop_s": 1.5, "drop": 1.0},
        {"link": "zenoh", "kinds": ["batch"], "start_s": 2.0, "stop_s": 2.2, "drop": 1.0},
        {"link": "zenoh", "kinds": ["interrupt"], "start_s": 2.5, "stop_s": 3.0, "delay_s": 0.08},
        {"link": "can", "kinds": ["rpdo", "tpdo"], "start_s": 0.5, "drop": 0.05, "duplicate": 0.05},
        seed=9,
    )
    controller = {"duration_s": 3.5, **FAST, "fault_scenario": faults}
    a = run_cosim(controller=dict(controller), dsp=dict(FAST_DSP))
    b = run_in_process(controller=dict(controller), dsp=dict(FAST_DSP))
    assert a.result.error is None and b.result.error is None
    _same(a, b)
    keys = (
        "fault_dropped_interrupt",
        "fault_dropped_batch",
        "fault_delayed_interrupt",
        "fault_dropped_rpdo",
        "fault_duplicated_rpdo",
        "interrupts_lost",
        "deadline_misses",
    )
    assert {k: a.result.counters.get(k) for k in keys} == {k: b.result.counters.get(k) for k in keys}


def test_a_dropped_interrupt_that_comes_late_still_gives_the_cosims_record(monkeypatch: pytest.MonkeyPatch) -> None:
    """Lockstep waits for a dropped interrupt too: it still releases the DSP's
    block, which the next batch waits for. Here the DSP takes 0.25 s of wall
    time over each batch whose interrupt the fault drops (as on a loaded
    host), so it comes long after its due tick; the record is still the
    co-simulation's (before, the controller went on at the due tick and sent
    its next batch whenever the late interrupt happened to come: 2 of 4 runs
    differed on a loaded host)."""
    import time as _time

    from dsp_service.core import DspCore
    from workbench.composition import run_in_process

    faults = scenario({"link": "zenoh", "kinds": ["interrupt"], "start_s": 1.0, "stop_s": 1.5, "drop": 1.0}, seed=9)
    controller = {"duration_s": 2.5, **FAST, "fault_scenario": faults}
    a = run_cosim(controller=dict(controller), dsp=dict(FAST_DSP))
    original = DspCore.process_fields

    def slow(core: DspCore, batch: Any, admission: Any) -> dict[str, Any]:
        if 1.0 <= batch.sim_time_s + batch.n_samples / batch.sample_rate_hz < 1.6:
            _time.sleep(0.25)
        return original(core, batch, admission)

    monkeypatch.setattr(DspCore, "process_fields", slow)
    b = run_in_process(controller=dict(controller), dsp=dict(FAST_DSP))
    assert a.result.error is None and b.result.error is None
    assert a.result.counters.get("fault_dropped_interrupt", 0) >= 3
    _same(a, b)


def test_timing_test_report_gives_verdicts_percentiles_and_histograms(tmp_path: Path) -> None:
    from workbench.cli import main
    from workbench.timing_test.report import run_lengths

    assert run_lengths([0, 1, 1, 0, 1, 0, 0, 1, 1, 1]) == [2, 1, 3] and run_lengths([]) == []
    spec = tmp_path / "s.json"
    spec.write_text(
        json.dumps(
            {
                "name": "t",
                "duration_s": 2.0,
                "settings": {"controller": FAST, "dsp": FAST_DSP},
                "faults": [{"link": "zenoh", "kinds": ["interrupt"], "start_s": 0.5, "stop_s": 1.0, "drop": 1.0}],
            }
        )
    )
    rc = main(["timing-test", str(spec), "--out", str(tmp_path / "r"), "--max-consecutive-misses", "10"])
    report = json.loads((tmp_path / "r" / "report.json").read_text())
    assert rc == 0 and report["passed"]
    assert report["miss_run_lengths"]["longest"] == 5  # the five batches whose interrupts were due in [0.5, 1) s
    misses = next(c for c in report["criteria"] if c["name"] == "consecutive deadline misses")
    assert misses["judged"] == report["batches"] > 5 and misses["verdict"] == "pass"
    run = report["run_verdict"]  # the run went on through the lost interrupts: degraded, exit 0
    assert run["verdict"] == "DEGRADED" and run["findings"]["interrupts_lost"] == 5 and run["exit_code"] == 0
    assert report["host"]["cpus"] and "load_average_after" in report["host"]
    assert (tmp_path / "r" / "hist_tet.png").stat().st_size > 1000
    assert main(["timing-test", str(spec), "--out", str(tmp_path / "r2")]) == 1  # default: never two misses in a row


def test_a_timing_test_too_short_to_break_its_criteria_fails(tmp_path: Path) -> None:
    """0.05 s: ten ticks, no batch answered: no criterion can be broken, so none passes."""
    from workbench.cli import main

    spec = tmp_path / "s.json"
    spec.write_text(json.dumps({"name": "t", "duration_s": 0.05, "settings": {"controller": FAST, "dsp": FAST_DSP}, "faults": []}))
    assert main(["timing-test", str(spec), "--out", str(tmp_path / "r")]) == 1
    report = json.loads((tmp_path / "r" / "report.json").read_text())
    misses = next(c for c in report["criteria"] if c["name"] == "consecutive deadline misses")
    assert report["batches"] == 0 and misses["judged"] == 0
    assert misses["verdict"] == "fail (too few batches to judge: 0, at least 2)" and not report["passed"]
    assert "too few batches to judge: 0" in (tmp_path / "r" / "report.md").read_text()


def test_lost_interrupts_under_policy_degrade_make_the_oatf_fall_back() -> None:
    """Adaptive OATF; from 5 s every interrupt is lost; the deadline monitor
    (policy degrade) stays active: the OATF tuning's ``fallback=fixed`` returns to the
    design frequency, ``last`` freezes the last good design."""
    faults = scenario({"link": "zenoh", "kinds": ["interrupt"], "start_s": 5.0, "drop": 1.0})
    common = {"duration_s": 7.0, "oatf_mode": "adaptive", "policies": "deadline=degrade", "fault_scenario": faults, **FAST}
    hz = {}
    for fallback in ("fixed", "last"):
        run = run_cosim(controller={**common, "oatf": {"fallback": fallback}}, dsp={"fft_width": 256, "emulated_latency_s": 0.05})
        hz[fallback] = _columns(run)["oatf_hz"]
        assert run.result.error is None and run.controller.law.degraded
    before, after = slice(0, 5 * 200), slice(int(5.6 * 200), None)  # past the last batch sent before 5 s
    assert np.array_equal(hz["fixed"][before], hz["last"][before])
    assert np.any(hz["fixed"][before] != 4.4)  # it had adapted
    assert np.all(hz["fixed"][after] == 4.4)
    frozen = hz["last"][after]
    assert np.all(frozen == hz["last"][5 * 200 - 1]) and frozen[0] != 4.4


def test_in_real_time_a_delayed_interrupt_is_held_then_applied_late() -> None:
    """Real time (one process, virtual CAN, in-process zenoh): interrupts
    delayed 300 ms, twice the deadline, are misses, then applied (not lost).
    Counts only, no time is asserted."""
    from workbench.composition import run_in_process

    faults = scenario({"link": "zenoh", "kinds": ["interrupt"], "start_s": 0.5, "stop_s": 1.5, "delay_s": 0.3})
    run = run_in_process(controller={"duration_s": 2.5, **FAST, "fault_scenario": faults}, dsp=dict(FAST_DSP), common={"clock": "realtime"})
    c = run.result.counters
    assert run.result.error is None
    assert c["fault_delayed_interrupt"] >= 1 and c["deadline_misses"] >= 1
    assert c["interrupts_applied"] >= c["fault_delayed_interrupt"]
    assert "hop_dsp_compute" in run.controller.hops.stats()


def test_the_up_summary_verdict_reads_the_controller_health() -> None:
    from workbench.timing_test.report import health_verdict

    run = _cosim(scenario({"link": "zenoh", "kinds": ["interrupt"], "start_s": 1.0, "stop_s": 1.3, "drop": 1.0}))
    health = run.health["controller"].model_dump()
    assert health["counters"]["deadline_miss_run_max"] == 3
    assert "hop_sync_to_tpdo" in health["latencies"]
    assert health_verdict(health) == "FAIL: deadline misses in a row 3 (<= 1)"


def test_the_verdict_judges_the_rig_and_reports_the_hosts_latency_class() -> None:
    """A general-purpose kernel's wake-up p99 of ~1 ms is the host's class, not
    a failure of the rig: reported beside the verdict, judged only when strict."""
    from workbench.timing_test.report import Criteria, health_verdict, latency_class

    slow = {"count": 6000, "p50": 1e-4, "p99": 1.128e-3, "p999": 2e-3, "max": 3e-3}
    healthy: dict[str, Any] = {"latencies": {"sync_jitter": slow}, "counters": {"deadline_miss_run_max": 0, "overrun_run_max": 1, "overruns": 3}}
    assert health_verdict(healthy) == "PASS: deadline misses in a row 0 (<= 1); overruns 3, at most 1 in a row (counted, not judged)"
    line = latency_class(healthy, {"preempt_rt": False})
    assert line == "general-purpose kernel: wake-up p99 1128 us, p99.9 2000 us (outside the PREEMPT_RT class, p99 <= 250 us)"
    strict = health_verdict(healthy, Criteria(strict=True))
    assert strict == "FAIL: deadline misses in a row 0 (<= 1), overruns in a row 1 (<= 1), wake-up p99 1128 us (<= 250), wake-up p99.9 2000 us (<= 1000)"
    # Overruns against the same run's sleep-only loop: 1 in 1000 ticks there allows 12 in 6000 here.
    assert health_verdict(healthy, overrun_floor_per_tick=1e-3) == ("PASS: deadline misses in a row 0 (<= 1), overruns 3 (<= 12: 2x the sleep-only loop's)")
    many = {**healthy, "counters": {**healthy["counters"], "overruns": 40}}
    verdict = health_verdict(many, overrun_floor_per_tick=1e-3)
    assert verdict is not None and verdict.startswith("FAIL: ")
    assert latency_class({"latencies": {"sync_jitter": {"count": 0}}}) is None  # cosim: no wall-clock wake-ups
