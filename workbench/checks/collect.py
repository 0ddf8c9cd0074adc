"""The results a test made, and the assertions over them.

Every check hands its result to :func:`collected`: inside :func:`collecting`
(the pytest plugin opens one around each test's setup, call and teardown) the
result is kept for the test's report (JUnit properties, figures in the HTML
report); outside one it is only returned. :func:`assert_check` and
:func:`check` turn results into assertions whose message is the check's line.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

from workbench.checks.result import CheckResult

_current: ContextVar[list[CheckResult] | None] = ContextVar("ralf_hil_check_results", default=None)


@contextmanager
def collecting() -> Iterator[list[CheckResult]]:
    """Keep every result made in this context (this thread's, or a task's) in the list yielded."""
    results: list[CheckResult] = []
    token = _current.set(results)
    try:
        yield results
    finally:
        _current.reset(token)


def collected(result: CheckResult) -> CheckResult:
    """Keep ``result`` in the current collection, if any; returns it."""
    results = _current.get()
    if results is not None:
        results.append(result)
    return result


def assert_check(result: CheckResult) -> CheckResult:
    """``result`` if it passed; else an ``AssertionError`` whose message is its line
    (``overshoot_below(phi1) FAIL: overshoot 23.4 % against a limit of 10 %``).
    An INVALID result (it compared nothing) fails too."""
    __tracebackhide__ = True
    if not result.passed:
        raise AssertionError(result.line())
    return result


def check(*results: CheckResult) -> tuple[CheckResult, ...]:
    """Judge several results at once: an ``AssertionError`` naming every one that did not
    pass, a line each (so one failing check does not hide the next)."""
    __tracebackhide__ = True
    if not results:
        raise AssertionError("check() was given no result: it compared nothing")
    failed = [r.line() for r in results if not r.passed]
    if failed:
        raise AssertionError(f"{len(failed)} of {len(results)} checks did not pass:\n" + "\n".join(failed))
    return results
