"""The start-up wait lines (service_kit.waits), on a clock the test sets: the
beginning said once, a reminder every period while the wait goes on, the end
with the time since the waits began, the steps in order."""

from __future__ import annotations

import logging
import threading

import pytest

from service_kit.waits import Awaited, WaitLog, log_waits


class Flag:
    def __init__(self) -> None:
        self.up = False

    def __call__(self) -> bool:
        return self.up


def test_a_wait_is_said_once_reminded_every_period_and_ended() -> None:
    plant = Flag()
    waits = WaitLog([Awaited("the plant node 1 on CAN (its boot-up or heartbeat)", plant, "plant node 1 heard")], started_s=100.0, remind_s=5.0)
    assert waits.step(100.0) == ["waiting for the plant node 1 on CAN (its boot-up or heartbeat)..."]
    assert waits.step(101.0) == [] and waits.step(104.9) == []
    assert waits.step(105.0) == ["still waiting for the plant node 1 on CAN (its boot-up or heartbeat): 5 s so far"]
    assert waits.step(109.0) == []
    assert waits.step(110.2) == ["still waiting for the plant node 1 on CAN (its boot-up or heartbeat): 10 s so far"]
    plant.up = True
    assert waits.step(111.25) == ["plant node 1 heard after 11.2 s"]
    assert waits.done and waits.step(200.0) == []


def test_steps_follow_in_order_and_one_already_there_is_said_and_ended_at_once() -> None:
    plant, dsp = Flag(), Flag()
    plant.up = True
    waits = WaitLog([Awaited("the plant", plant, "plant heard"), Awaited("the DSP", dsp, lambda: "DSP ready")], started_s=0.0, remind_s=5.0)
    assert waits.step(0.5) == ["waiting for the plant...", "plant heard after 0.5 s", "waiting for the DSP..."]
    assert waits.step(5.4) == []  # the DSP's wait began at 0.5: its first reminder is due at 5.5
    assert waits.step(5.5) == ["still waiting for the DSP: 5 s so far"]
    dsp.up = True
    assert waits.step(6.0) == ["DSP ready after 6.0 s"]
    assert waits.done


def test_the_end_line_may_say_how_the_wait_ended() -> None:
    ready, answered = Flag(), Flag()
    waits = WaitLog([Awaited("the DSP", ready, lambda: "DSP ready" if answered() else "no DSP answered")], started_s=0.0)
    waits.step(0.0)
    ready.up = True
    assert waits.step(60.0) == ["no DSP answered after 60.0 s"]


@pytest.mark.timeout(30)
def test_the_thread_logs_the_lines_and_ends_when_the_waits_are_over(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="waits-test")
    plant = Flag()
    thread = log_waits([Awaited("the plant", plant, "plant heard")], logging.getLogger("waits-test"), threading.Event(), remind_s=0.01, poll_s=0.005)
    while not any("still waiting for the plant" in r.getMessage() for r in caplog.records):
        thread.join(0.01)
    plant.up = True
    thread.join(20.0)
    assert not thread.is_alive()
    messages = [r.getMessage() for r in caplog.records]
    assert messages[0] == "waiting for the plant..." and messages[-1].startswith("plant heard after ")
    assert messages.count("waiting for the plant...") == 1


@pytest.mark.timeout(30)
def test_the_thread_ends_at_stop_with_the_wait_unfinished(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.INFO, logger="waits-test")
    stop = threading.Event()
    thread = log_waits([Awaited("the DSP", Flag(), "DSP ready")], logging.getLogger("waits-test"), stop, poll_s=0.005)
    stop.set()
    thread.join(20.0)
    assert not thread.is_alive()
    assert not any("DSP ready" in r.getMessage() for r in caplog.records)
