"""The run's verdict (workbench.verdict) on constructed summaries: each
finding lands in its level, the worst level wins, every count the rule
looked at is in the findings, and the exit code follows the level."""

from __future__ import annotations

from typing import Any

import pytest

from workbench.log_counts import count_log_lines, counting_warnings
from workbench.verdict import judge


def summary(controller: dict[str, int] | None = None, plant: dict[str, int] | None = None, **more: Any) -> dict[str, Any]:
    return {
        "controller": {"ticks": 1000, "deadline_misses": 0},
        "health": {
            "controller": {"counters": {"deadline_misses": 0, "interrupts_lost": 0, **(controller or {})}},
            "plant": {"counters": {"watchdog_trips": 0, **(plant or {})}, "last_miss": more.pop("plant_last_miss", None)},
        },
        "exit_codes": {"controller": 0, "plant": 0, "dsp": 0},
        **more,
    }


def test_a_clean_run_passes_and_says_what_it_looked_at() -> None:
    v = judge(summary(), "PASS: deadline misses in a row 0 (<= 1)")
    assert (v.level, v.reasons, v.exit_code) == ("PASS", (), 0)
    assert v.findings["control_ticks"] == 1000 and v.findings["interrupts_lost"] == 0 and v.findings["watchdog_trips"] == 0
    assert v.line() == "PASS: nothing went wrong"


@pytest.mark.parametrize(
    ("controller", "plant", "reason"),
    [
        ({"deadline_misses": 1}, {}, "deadline misses (interrupts not there by their deadline): 1"),
        ({"interrupts_lost": 13}, {}, "interrupts lost (never came): 13"),
        ({"schedule_resyncs": 2}, {}, "schedules re-based (the loop fell behind): 2"),
        ({"periods_skipped": 35}, {}, "sample periods skipped: 35"),
        ({"dsp_lost": 1}, {}, "DSP lost: 1"),
        ({}, {"watchdog_trips": 4}, "plant SYNC watchdog trips (valves held at zero): 4"),
        ({}, {"fmu_step_discards": 1}, "plant model steps discarded (outputs held): 1"),
        ({}, {"fmu_non_finite_outputs": 2}, "plant model steps with non-finite outputs (outputs held): 2"),
    ],
)
def test_each_trouble_on_the_way_degrades(controller: dict[str, int], plant: dict[str, int], reason: str) -> None:
    v = judge(summary(controller, plant), "PASS: deadline misses in a row 1 (<= 1)")
    assert v.level == "DEGRADED" and v.reasons == (reason,) and v.exit_code == 0


def test_warning_and_error_lines_in_a_log_degrade_and_are_counted_per_service() -> None:
    v = judge(summary(log_warnings={"controller": 73, "plant": 0, "dsp": 2}, log_errors={"controller": 0}))
    assert v.level == "DEGRADED"
    assert v.reasons == ("WARNING lines in the logs: controller 73, dsp 2",)
    assert v.findings["log_warnings"] == {"controller": 73, "plant": 0, "dsp": 2}


@pytest.mark.parametrize(
    ("more", "timing", "reason"),
    [
        ({"failure": "controller exited with 3"}, None, "rig failed: controller exited with 3"),
        ({"exit_codes": {"controller": 4, "plant": 0}}, None, "exit codes controller=4"),
        ({}, "FAIL: deadline misses in a row 2 (<= 1)", "timing FAIL: deadline misses in a row 2 (<= 1)"),
    ],
)
def test_a_failed_service_or_timing_fails_over_any_degradation(more: dict[str, Any], timing: str | None, reason: str) -> None:
    v = judge(summary({"interrupts_lost": 3}, **more), timing)
    assert v.level == "FAIL" and v.exit_code == 1
    assert v.reasons == (reason, "interrupts lost (never came): 3")
    assert v.by_level == {"INVALID": [], "FAIL": [reason], "DEGRADED": ["interrupts lost (never came): 3"]}
    assert v.as_dict()["by_level"] == v.by_level


@pytest.mark.parametrize(
    ("controller", "plant"),
    [({}, {"fmu_step_errors": 1}), ({}, {"fmu_terminated": 1}), ({"plant_model_dead": 1}, {})],
)
def test_a_dead_plant_model_makes_the_run_invalid_over_a_failure(controller: dict[str, int], plant: dict[str, int]) -> None:
    s = summary(controller, plant, failure="plant model dead: EMCY PLANT_MODEL_FAULT", plant_last_miss="FMU doStep at 1.500 s returned error")
    v = judge(s, "PASS: deadline misses in a row 0 (<= 1)")
    assert v.level == "INVALID" and v.exit_code == 1 and v.findings["plant_model_dead"] is True
    assert v.reasons[0].startswith("plant model dead (FMU doStep at 1.500 s returned error)")
    assert v.reasons[1] == "rig failed: plant model dead: EMCY PLANT_MODEL_FAULT"


def test_no_tick_is_invalid_and_a_missing_summary_part_is_no_crash() -> None:
    v = judge({"controller": None, "health": {}, "exit_codes": {}})
    assert v.level == "INVALID" and v.reasons == ("no control tick",)


def test_log_lines_are_counted_by_their_level_field_only() -> None:
    text = "\n".join(
        [
            "2026-12-03 05:12:03,000 controller INFO controller: timing verdict PASS (no WARNING, no ERROR: words in a message)",
            "2026-12-03 05:12:04,000 controller WARNING controller: loop 35 periods late: schedule re-based, samples skipped",
            "2026-12-03 05:12:05,000 controller ERROR controller: plant fault: plant heartbeat lost; valves to zero",
            "2026-12-03 05:12:05,500 controller CRITICAL controller: x",
            "Traceback WARNING ERROR",
        ]
    )
    assert count_log_lines(text) == (1, 2)


def test_records_logged_in_this_process_are_counted_per_service() -> None:
    import logging

    with counting_warnings() as (warnings, errors):
        logging.getLogger("controller.service").warning("loop 3 periods late")
        logging.getLogger("plant_emulator.fmu.plant").warning("FMU step failed")
        logging.getLogger("dsp_service.service").error("x")
        logging.getLogger("controller").info("not counted")
    logging.getLogger("controller").warning("after: not counted")
    assert dict(warnings) == {"controller": 1, "plant": 1} and dict(errors) == {"dsp": 1}


def test_a_test_knob_degrades_and_a_reconfiguration_is_noted_without_a_level() -> None:
    knob = judge(summary({"reconfigurations": 2, "test_knob_changes": 1}))
    assert knob.level == "DEGRADED" and knob.reasons[0].startswith("test knobs set under the run: 1")
    assert knob.notes == ("configuration changed under the run by 1 command(s) (ralf-hil reconfigure)",)
    tool = judge(summary({"reconfigurations": 3}), "PASS: deadline misses in a row 0 (<= 1)")
    assert tool.level == "PASS" and tool.findings["reconfigurations"] == 3
    assert tool.line() == "PASS: nothing went wrong (note: configuration changed under the run by 3 command(s) (ralf-hil reconfigure))"
    assert tool.as_dict()["notes"] == list(tool.notes)
