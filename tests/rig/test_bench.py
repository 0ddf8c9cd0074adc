"""``ralf-hil bench``: argument parsing, the report's structure and the
floors in quick mode. No timing thresholds: only that numbers are measured
(positive, finite) and reported where the JSON says."""

from __future__ import annotations

import argparse
import io
import json
import math
import unittest.mock
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rich.console import Console

from workbench import bench
from workbench.bench import items as bench_items
from workbench.bench.stats import machine_info, ratios, summarize
from workbench.cli import build_parser

LATENCY_KEYS = ("n", "p50_us", "p99_us", "p999_us", "max_us")


def _parse(*argv: str) -> argparse.Namespace:
    return build_parser().parse_args(["bench", *argv])


def test_defaults_and_quick() -> None:
    full = bench.options_from_args(_parse())
    assert full["items"] == ["zenoh", "can", "realtime", "lockstep", "cosim", "runs", "dsp", "dsp-rigs", "hotpath", "fmu", "can-wire"]
    assert full["quick"] is False and full["duration_s"] == 10.0 and full["iterations"] == 2000
    quick = bench.options_from_args(_parse("--quick"))
    assert quick["duration_s"] < full["duration_s"] and quick["iterations"] < full["iterations"]
    assert quick["items"] == ["zenoh", "can", "realtime", "cosim", "hotpath"]  # a smoke test: one real-time rig, no lockstep or DSP rigs
    args = _parse("--quick", "--duration", "4.5", "--iterations", "7", "--json", "x.json")
    opts = bench.options_from_args(args)
    assert (opts["duration_s"], opts["iterations"]) == (4.5, 7)  # explicit values win over --quick
    assert args.json == "x.json" and args.func is bench.cmd_bench


def test_realtime_acceptance_options_reach_the_context(tmp_path: Path) -> None:
    args = _parse(
        "--only",
        "realtime",
        "--rate",
        "1000:60",
        "--rate",
        "200",
        "--burners",
        "2",
        "--batch-period",
        "0.3",
        "--floor-seconds",
        "60",
        "--rt-priority",
        "10",
        "--cpu-affinity",
        "1",
    )
    opts = bench.options_from_args(args)
    assert opts["rates"] == [[1000.0, 60.0], [200.0, None]]
    assert (opts["burners"], opts["batch_period_s"], opts["floor_s"], opts["rt_priority"], opts["cpu_affinity"]) == (2, 0.3, 60.0, 10, "1")
    seen: list[bench_items.BenchContext] = []

    def capture(ctx: bench_items.BenchContext, result: dict[str, Any]) -> None:
        seen.append(ctx)

    with unittest.mock.patch.dict(bench_items.ITEMS, {"realtime": capture}):
        bench.run_bench(opts, tmp_path)
    ctx = seen[0]
    assert ctx.rates == ((1000.0, 60.0), (200.0, None)) and ctx.burners == 2 and ctx.cpu_affinity == "1"
    for bad in (["--rate", "fast"], ["--rate", "1000:-1"], ["--rate", "0"], ["--cpu-affinity", "x"], ["--burners", "99"]):
        with pytest.raises(SystemExit):
            _parse(*bad)


def test_cpu_burners_run_for_the_block_and_are_gone_after_it() -> None:
    with bench_items.cpu_burners(2) as procs:
        assert len(procs) == 2 and all(p.poll() is None for p in procs)
    assert all(p.poll() is not None for p in procs)


def test_only_selects_items_in_order_without_duplicates() -> None:
    opts = bench.options_from_args(_parse("--only", "dsp", "zenoh", "--only", "dsp"))
    assert opts["items"] == ["dsp", "zenoh"]
    assert bench.options_from_args(_parse("--floors-only"))["items"] == ["zenoh", "can"]


@pytest.mark.parametrize(
    "argv",
    [
        ["--only", "nonsense"],
        ["--only"],
        ["--duration", "0"],
        ["--duration", "-3"],
        ["--duration", "nan"],
        ["--duration", "soon"],
        ["--iterations", "0"],
        ["--iterations", "1.5"],
    ],
)
def test_bad_arguments_exit_with_one_line(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        _parse(*argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("ralf-hil bench: argument ") and err.endswith("(see ralf-hil bench --help)\n") and err.count("\n") == 1


def test_summaries_and_ratios() -> None:
    s = summarize([0.001, 0.002, 0.003, 0.004])
    assert s["n"] == 4 and s["min_us"] == pytest.approx(1000) and s["max_us"] == pytest.approx(4000)
    assert s["p50_us"] == pytest.approx(2500)
    r = ratios(s, summarize([0.0005] * 4))
    assert r["p50"] == pytest.approx(5.0) and r["max"] == pytest.approx(8.0)
    with pytest.raises(ValueError):
        summarize([])
    with pytest.raises(ValueError):
        summarize([0.001, float("nan")])
    info = machine_info()
    for key in ("platform", "cpu_model", "cores", "python", "packages", "date"):
        assert info[key]
    assert info["packages"]["eclipse-zenoh"]


def test_a_failing_or_missing_item_is_reported_not_raised(monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(ctx: Any, result: dict[str, Any]) -> None:
        result["measurements"]["half"] = bench_items.latency(summarize([0.001]))
        raise RuntimeError("the service fell over")

    def missing(ctx: Any, result: dict[str, Any]) -> None:
        bench_items.requires("no_such_module_for_bench_tests")

    monkeypatch.setitem(bench_items.ITEMS, "broken", broken)
    monkeypatch.setitem(bench_items.ITEMS, "missing", missing)
    ctx = bench_items.BenchContext()
    failed = bench_items.run_item("broken", ctx)
    assert failed["status"] == "failed"
    assert "half" in failed["measurements"]  # what was measured before the failure is kept
    assert "the service fell over" in failed["errors"][0]
    skipped = bench_items.run_item("missing", ctx)
    assert skipped["status"] == "skipped" and "no_such_module_for_bench_tests" in skipped["skipped"][0]
    report = {"machine": machine_info(), "items": {"broken": failed, "missing": skipped}}
    report["machine"]["load_average_at_end"] = None
    buf = io.StringIO()
    Console(file=buf, width=200).print(bench.render(report))
    text = buf.getvalue()
    assert "broken (failed)" in text and "the service fell over" in text
    assert "missing (skipped)" in text and "no_such_module_for_bench_tests" in text


def test_an_item_that_measured_nothing_is_not_ok(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(bench_items.ITEMS, "empty", lambda ctx, result: None)
    empty = bench_items.run_item("empty", bench_items.BenchContext())
    assert empty["status"] == "failed" and empty["errors"] == ["no measurement made"]


def _check_latency(m: dict[str, Any]) -> None:
    assert m["kind"] == "latency"
    for key in LATENCY_KEYS:
        assert isinstance(m[key], (int, float)) and math.isfinite(m[key]) and m[key] > 0, (key, m)
    assert m["p50_us"] <= m["p99_us"] <= m["p999_us"] <= m["max_us"]


@pytest.mark.timeout(120)
def test_quick_floors_write_a_complete_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from workbench.cli import main

    out = tmp_path / "bench.json"
    code = main(["bench", "--quick", "--floors-only", "--iterations", "30", "--json", str(out), "--log-dir", str(tmp_path / "logs")])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    report = json.loads(out.read_text())
    assert report["schema"] == bench.SCHEMA
    assert report["options"]["quick"] is True and report["options"]["iterations"] == 30
    for key in ("date", "platform", "cpu_model", "cores", "python", "packages", "load_average_at_start", "load_average_at_end"):
        assert key in report["machine"]
    assert set(report["items"]) == {"zenoh", "can"}
    zen = report["items"]["zenoh"]
    assert zen["status"] == "ok", zen
    assert zen["config"]["payload_bytes"] == 56 + 8 * 4 * 20  # the 20-sample 2-in/2-out batch
    _check_latency(zen["measurements"]["udp_pingpong"])
    z = zen["measurements"]["zenoh_pingpong"]
    _check_latency(z)
    assert z["n"] == 30 and z["floor"] == "udp_pingpong"
    assert all(math.isfinite(v) and v > 0 for v in z["ratio"].values())
    tls = zen["measurements"]["zenoh_pingpong_tls"]  # the same over mutual TLS, against the TCP one
    _check_latency(tls)
    assert tls["n"] == 30 and tls["floor"] == "zenoh_pingpong"
    can_item = report["items"]["can"]
    assert can_item["status"] == "ok", can_item
    _check_latency(can_item["measurements"]["can_pingpong"])
    for name in ("can_junk_reject", "can_junk_reject (controller link)", "can_junk_reject (python-can stock bus)", "can_frame_read"):
        junk = can_item["measurements"][name]  # per datagram, against a bare recvmsg in the same run
        _check_latency(junk)
        assert junk["floor"] == "udp_recv_floor" and junk["n"] == 20
    assert report["wall_s"] > 0
    assert "zenoh_pingpong" in printed.out and "can_pingpong" in printed.out  # the table


@pytest.mark.timeout(60)
def test_the_paced_zenoh_echo_holds_each_answer_as_asked(tmp_path: Path) -> None:
    """The paced floor's echo busy-waits the hold it was given (``--hold-key``,
    acknowledged) before each answer, and the pinger runs its untimed work
    before each round trip: every round trip lasts at least the hold."""
    from workbench.bench.pingers import ZenohPinger, zenoh_session
    from workbench.bench.procs import Child, private_rig_id
    from workbench.launcher import free_tcp_port

    rig = private_rig_id("paced")
    port = free_tcp_port()
    ping, pong, hold = f"ralf/{rig}/bench/ping", f"ralf/{rig}/bench/pong", f"ralf/{rig}/bench/hold"
    prepared: list[int] = []
    with Child.peer("zenoh-echo", "--listen", f"tcp/127.0.0.1:{port}", "--ping", ping, "--pong", pong, "--hold-key", hold, log_dir=tmp_path) as echo:
        echo.read_tagged("READY", 30)
        session = zenoh_session(connect=[f"tcp/127.0.0.1:{port}"])
        try:
            pinger = ZenohPinger(session, ping, pong, 64, prepare=lambda: prepared.append(1))
            pinger.connect()
            bench_items.set_echo_hold(session, hold, 0.003)
            rtts = [pinger.once() for _ in range(5)]
            pinger.close()
        finally:
            session.close()
    assert len(prepared) == 5
    assert min(rtts) >= 0.003  # a lower bound: a loaded host only makes it longer


def test_a_paced_pinger_starts_its_round_trips_one_period_apart() -> None:
    """The paced floor sleeps so that each round trip starts one period after
    the last (none when the last took longer), as a loop's ticks start."""
    from workbench.bench.pingers import PacedPinger

    now = [0.0]
    starts: list[float] = []

    class Inner:
        name = "inner"

        def once(self) -> float:
            starts.append(now[0])
            now[0] += 0.0003 if len(starts) != 3 else 0.007  # the third round trip overruns the period
            return 0.0003

    def sleep(s: float) -> None:
        assert s > 0
        now[0] += s

    paced = PacedPinger(Inner(), 0.005, clock=lambda: now[0], sleep=sleep)
    for _ in range(5):
        paced.once()
    assert paced.name == "inner paced"
    assert np.allclose(np.diff(starts), [0.005, 0.005, 0.007, 0.005])
    with pytest.raises(ValueError):
        PacedPinger(Inner(), 0.0)
