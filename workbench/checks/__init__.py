"""Named signal checks for HIL tests.

Each check takes signals (:class:`Signal`; a run record's by name:
:func:`signal`) and returns a :class:`CheckResult`: PASS, FAIL or INVALID
(it compared nothing), the measured value against the limit, one line that
says so (:meth:`CheckResult.explain`) and a figure (:meth:`CheckResult.figure`).
:func:`assert_check` and :func:`check` make them assertions; in a pytest test
the ``ralf_hil`` plugin keeps every result for the JUnit XML (a property per
check) and the HTML report (a figure per check). docs/signal-checks.md.
"""

from workbench.checks.bounds import rms_below, stays_within
from workbench.checks.collect import assert_check, check, collecting
from workbench.checks.deadlines import no_deadline_miss_streak
from workbench.checks.detection import detected_within
from workbench.checks.modes import mode_frequency_within
from workbench.checks.record_signals import SignalNotInRecord, deadline_misses, signal
from workbench.checks.result import CheckResult
from workbench.checks.signal import Signal
from workbench.checks.step import overshoot_below, settles_within
from workbench.checks.tracking import follows_reference

__all__ = [
    "CheckResult",
    "Signal",
    "SignalNotInRecord",
    "assert_check",
    "check",
    "collecting",
    "deadline_misses",
    "detected_within",
    "follows_reference",
    "mode_frequency_within",
    "no_deadline_miss_streak",
    "overshoot_below",
    "rms_below",
    "settles_within",
    "signal",
    "stays_within",
]
