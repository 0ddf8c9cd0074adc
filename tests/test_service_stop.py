"""How a service ends after SIGINT/SIGTERM (service_kit.runtime): the exit
code, and the guard that ends a start-up that cannot stop in order (a
kernel compiling), driven here with its exit injected and readiness set
by hand; no signal is sent."""

from __future__ import annotations

import threading
from collections.abc import Iterator

import pytest

from service_kit import readiness
from service_kit.interrupt import INTERRUPTED
from service_kit.runtime import end_a_start_that_cannot_stop, exit_code


def test_exit_code_is_130_after_ctrl_c_0_after_sigterm_and_a_fault_keeps_its_own() -> None:
    assert exit_code(0, ["SIGINT"]) == INTERRUPTED == 130
    assert exit_code(0, ["SIGTERM"]) == 0
    assert exit_code(0, []) == 0
    assert exit_code(3, ["SIGINT"]) == 3  # a plant fault stays a plant fault


@pytest.fixture
def not_ready() -> Iterator[None]:
    was = readiness.READY.is_set()
    readiness.READY.clear()
    yield None
    if was:
        readiness.READY.set()


def _guard(received: list[str], finished: threading.Event) -> tuple[threading.Event, list[int], threading.Thread]:
    stop = threading.Event()
    ended: list[int] = []
    thread = end_a_start_that_cannot_stop(stop, finished, received, grace_s=0.01, end=ended.append)
    return stop, ended, thread


@pytest.mark.timeout(30)
@pytest.mark.usefixtures("not_ready")
@pytest.mark.parametrize(("signal_name", "code"), [("SIGINT", 130), ("SIGTERM", 0)])
def test_a_start_still_going_after_the_grace_is_ended_with_the_orderly_code(signal_name: str, code: int) -> None:
    stop, ended, thread = _guard([signal_name], threading.Event())
    stop.set()
    thread.join(20.0)
    assert ended == [code]


@pytest.mark.timeout(30)
@pytest.mark.usefixtures("not_ready")
def test_a_service_that_stopped_in_order_is_left_alone() -> None:
    finished = threading.Event()
    stop, ended, thread = _guard(["SIGINT"], finished)
    finished.set()
    stop.set()
    thread.join(20.0)
    assert not thread.is_alive() and ended == []


@pytest.mark.timeout(30)
@pytest.mark.usefixtures("not_ready")
def test_a_ready_service_is_never_ended_by_the_guard() -> None:
    readiness.READY.set()
    stop, ended, thread = _guard(["SIGINT"], threading.Event())
    stop.set()
    thread.join(20.0)
    assert not thread.is_alive() and ended == []


@pytest.mark.timeout(30)
def test_the_guard_ends_with_the_run_when_no_signal_came() -> None:
    finished = threading.Event()
    stop, ended, thread = _guard([], finished)
    finished.set()
    thread.join(20.0)
    assert not thread.is_alive() and ended == [] and not stop.is_set()
