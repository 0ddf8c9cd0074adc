"""The identification step's bench (``ralf-hil bench --only dsp``) returns the structure it documents."""

from __future__ import annotations

import pytest

from workbench.bench.dsp_step import bench_identifier


def test_bench_returns_the_documented_structure() -> None:
    out = bench_identifier(n=256, repeats=5)
    for key in ("step_p50_us", "step_p99_us", "floor_p50_us", "floor_p99_us", "ratio_p50", "ratio_p99", "c40_fraction"):
        assert isinstance(out[key], float) and out[key] > 0, key
    assert out["n"] == 256 and out["repeats"] == 5
    assert isinstance(out["poles_found"], int)


def test_the_standalone_step_appends_a_batch_and_steps_on_a_full_history() -> None:
    from dsp_service import rfft_into
    from workbench.bench.dsp_step import StepPinger

    pinger = StepPinger(n=256, batch=20, repeats=3)
    assert pinger.fft_form in rfft_into.FORMS
    seen = pinger.idf.samples_in_history
    assert seen >= 256  # full before the first timed call
    start = pinger.pos
    times = [pinger.once() for _ in range(3)]
    assert all(t > 0 for t in times)
    assert pinger.pos == start + 3 * 20  # one batch appended per call
    for _ in range(pinger.u.shape[1] // 20):  # past the end of its data: it wraps, and still steps
        pinger.once()
    assert 256 <= pinger.pos <= pinger.u.shape[1]


def test_the_in_service_step_is_printed_against_the_standalone_one() -> None:
    from types import SimpleNamespace

    from workbench.bench.entries import new_result
    from workbench.bench.items import ZenohPingers, _zenoh_measurements

    rtt = [400e-6, 420e-6, 410e-6]
    dp = SimpleNamespace(name="dsp_batch_to_interrupt", compute_s=[150e-6, 160e-6, 170e-6], out_s=[1e-4] * 3, back_s=[1e-4] * 3, bad=0)
    samples = {"dsp_batch_to_interrupt": rtt, "dsp_step_standalone": [50e-6, 60e-6, 80e-6], "zenoh_pingpong": [200e-6] * 3, "udp_pingpong": [20e-6] * 3}
    result = new_result()
    _zenoh_measurements(result, samples, ZenohPingers([], dp=dp), None)  # type: ignore[arg-type]
    m = result["measurements"]
    assert m["dsp_compute"]["floor"] == "dsp_step_standalone"
    assert m["dsp_compute"]["ratio"]["p50"] == pytest.approx(160 / 60)
    assert m["dsp_step_standalone"]["p50_us"] == pytest.approx(60.0)
