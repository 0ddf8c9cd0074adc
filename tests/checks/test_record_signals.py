"""Signals read from a co-simulated run's record, the error for a name it does not
hold, the assertions over results, and every check's figure."""

from __future__ import annotations

import io
from collections.abc import Iterator

import numpy as np
import pytest
from matplotlib.figure import Figure

from workbench.checks import (
    CheckResult,
    Signal,
    SignalNotInRecord,
    assert_check,
    check,
    collecting,
    deadline_misses,
    detected_within,
    follows_reference,
    mode_frequency_within,
    no_deadline_miss_streak,
    overshoot_below,
    rms_below,
    settles_within,
    signal,
    stays_within,
)
from workbench.checks.figure import png
from workbench.checks.record_signals import names
from workbench.hil import HilRig, RunRecord


@pytest.fixture(scope="module")
def record() -> Iterator[RunRecord]:
    rig = HilRig(dsp_settings={"fft_width": 512, "alpha": 0.1})
    rig.plant.payload(attached=True, at_s=1.0)
    try:
        yield rig.run(duration_s=4.0)
    finally:
        rig.close()


def test_columns_come_over_the_record_time(record: RunRecord) -> None:
    phi = signal(record, "phi1")
    assert phi.unit == "rad" and len(phi) == record.ticks
    np.testing.assert_array_equal(phi.t, record.columns["t_s"])
    np.testing.assert_array_equal(phi.values, record.columns["phi1"])
    assert signal(record, "defl2_in").unit == "in" and signal(record, "u1_v").unit == "V" and signal(record, "f_id_hz").unit == "Hz"


def test_truth_fields_by_index(record: RunRecord) -> None:
    f1 = signal(record, "truth.modal_frequencies_hz[0]")
    np.testing.assert_array_equal(f1.values, record.true_first_mode_hz())
    np.testing.assert_array_equal(f1.t, [s.sim_time_s for s in record.truth])
    assert f1.unit == "Hz"
    attached = signal(record, "truth.payload_attached")
    assert attached.values[0] == 0.0 and attached.values[-1] == 1.0


def test_events_interrupts_counters_and_health(record: RunRecord) -> None:
    payload = signal(record, "events.payload")
    assert payload.kind == "events" and len(payload) == 1 and payload.t[0] == pytest.approx(1.0, abs=0.01)
    assert len(signal(record, "events.hard_stop")) == 0  # a kind the plant sends, none in this run
    missed = signal(record, "interrupts.deadline_missed")
    assert len(missed) == len(record.interrupts)
    poles = signal(record, "interrupts.poles[0].frequency_hz")
    expected = [i.poles[0].frequency_hz if i.poles else np.nan for i in record.interrupts]
    np.testing.assert_array_equal(poles.values, expected)
    count = signal(record, "counters.deadline_misses")
    assert count.kind == "count" and count.values[0] == record.counters["deadline_misses"] and count.t[0] == record.sim_time_s
    run_max = signal(record, "health.controller.deadline_miss_run_max")
    assert run_max.kind == "run_max"
    assert deadline_misses(record).name == "health.controller.deadline_miss_run_max"
    assert set(names(record)) >= {"phi1", "truth.deflections_in[1]", "events.payload", "interrupts.confidence", "counters.deadline_misses"}


@pytest.mark.parametrize(
    ("name", "hint"),
    [
        ("phi3", "(did you mean 'phi2'?)"),
        ("truth.deflections_in[2]", "truth.deflections_in[0..1]"),
        ("truth.modal_frequencies_hz", "truth.modal_frequencies_hz[0.."),
        ("events.payloads", "did you mean 'events.payload'?"),
        ("interrupts.poles[0].freq", "interrupts.poles[0.."),
        ("counters.deadline_miss", "counters.<"),
        ("health.dsp.nothing", "health.<service>.<counter> of "),
        ("nothing.at.all", "columns t_s, "),
    ],
)
def test_a_signal_the_record_does_not_hold_is_one_line_naming_it_and_what_exists(record: RunRecord, name: str, hint: str) -> None:
    with collecting() as made:
        with pytest.raises(SignalNotInRecord) as info:
            stays_within(signal(record, name), -1, 1)
    text = str(info.value)
    assert "\n" not in text and f"no signal {name!r}" in text and hint in text
    assert made == []  # raised before any check computed


def test_assertions_carry_the_line(record: RunRecord) -> None:
    good = stays_within(signal(record, "defl1_in"), -5.0, 5.0)
    assert assert_check(good) is good
    bad = stays_within(signal(record, "defl1_in"), -0.01, 0.01)
    with pytest.raises(AssertionError, match=r"^stays_within\(defl1_in\) FAIL: defl1_in left \[-0\.01, 0\.01\] in"):
        assert_check(bad)
    empty = rms_below(Signal.of([], [], "x"), 1.0)
    with pytest.raises(AssertionError, match="INVALID: compared nothing"):
        assert_check(empty)
    with pytest.raises(AssertionError) as info:
        check(good, bad, empty)
    assert str(info.value).splitlines() == ["2 of 3 checks did not pass:", bad.line(), empty.line()]
    with pytest.raises(AssertionError, match="no result"):
        check()


def test_results_are_collected_in_a_collection_only() -> None:
    sig = Signal.of([0.0, 1.0], [0.0, 0.5], "x")
    with collecting() as outer:
        a = stays_within(sig, 0, 1)
        with collecting() as inner:
            b = stays_within(sig, 0, 1)
        c = stays_within(sig, 0, 1)
    stays_within(sig, 0, 1)
    assert outer == [a, c] and inner == [b]


def test_property_value(record: RunRecord) -> None:
    result = stays_within(signal(record, "defl1_in"), -5.0, 5.0)
    level, measured, limit, unit = result.property_value().split(" ")
    assert (level, unit) == ("PASS", "unit=in") and limit in ("limit=5", "limit=-5")
    assert float(measured.removeprefix("measured=")) == pytest.approx(result.measured, rel=1e-3)


def every_check(record: RunRecord) -> list[CheckResult]:
    t = np.arange(0.0, 5.0, 0.01)
    step = Signal.of(t, 1.0 - np.exp(-3 * t) * np.cos(6 * t), "y")
    return [
        settles_within(step, 2.0),
        overshoot_below(step, 5.0),
        follows_reference(signal(record, "phi_ref1"), signal(record, "phi1"), tolerance=0.01, max_lag_s=0.1),
        stays_within(signal(record, "defl1_in"), -0.3, 0.3),
        rms_below(signal(record, "defl2_in"), 0.1),
        mode_frequency_within(signal(record, "f_id_hz"), signal(record, "truth.modal_frequencies_hz[0]"), rel_tol=0.1, max_missing=1.0),
        detected_within(signal(record, "events.payload"), signal(record, "truth.payload_attached"), 0.5),
        no_deadline_miss_streak(deadline_misses(record), 1),
        no_deadline_miss_streak(signal(record, "interrupts.deadline_missed"), 1),
        stays_within(Signal.of([], [], "empty"), 0, 1),
    ]


def test_every_check_draws_its_figure(record: RunRecord) -> None:
    for result in every_check(record):
        fig = result.figure()
        assert isinstance(fig, Figure) and fig.axes, result.name
        assert result.level in fig.get_suptitle()
        data = png(fig)
        assert data.startswith(b"\x89PNG") and len(data) > 2000
        buf = io.BytesIO()
        fig.savefig(buf, format="svg")
        assert b"<svg" in buf.getvalue()
