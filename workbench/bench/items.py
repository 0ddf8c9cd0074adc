"""The bench items. Each fills a result dict progressively, so what was
measured before a failure is still reported; each cleans up (sessions,
buses, child processes) whatever happens.

Result of an item::

    {"status": "ok" | "partial" | "failed" | "skipped",
     "measurements": {name: measurement, ...},   # in display order
     "config": {...}, "notes": [...], "errors": [...], "skipped": [...]}

A measurement is either a latency summary (``kind: "latency"``, µs:
``n, p50_us, p99_us, p999_us, max_us`` ...) or a scalar (``kind: "scalar"``,
``value``, ``unit``); either may name its ``floor`` (another measurement of
the same item, or a fixed reference given as ``floor_value``) and carry the
``ratio`` measured/floor (a dict by percentile for latencies).
"""

from __future__ import annotations

import importlib
import json
import math
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from protocol.batch_codec import encode_batch
from protocol.keys import Keys
from workbench.bench import can_junk
from workbench.bench.entries import BenchContext, Skip, latency, latency_vs_value, new_result, requires, scalar
from workbench.bench.pingers import (
    CanPinger,
    DspPinger,
    HealthWatch,
    PacedPinger,
    PlantPinger,
    UdpPinger,
    ZenohPinger,
    batch_size_bytes,
    can_bus,
    interleave,
    sample_batch,
    zenoh_session,
)
from workbench.bench.procs import BenchError, Child, clean_env, private_can_port, private_rig_id, tail
from workbench.bench.stats import from_latency_stats, ratios, summarize
from workbench.hostinfo import host_info
from workbench.launcher import free_tcp_port, free_tcp_ports
from workbench.timing_test.report import health_verdict, latency_class

CAN_GROUP = "239.74.163.2"
DSP_FFT_WIDTH = 2048
BATCH_SAMPLES = 20


def _measure_pingers(ctx: BenchContext, pingers: list[Any]) -> dict[str, list[float]]:
    ctx.say(f"  {ctx.iterations} round trips each of {', '.join(p.name for p in pingers)}")
    return interleave(pingers, ctx.iterations, ctx.warmup)


# --- 1. zenoh -------------------------------------------------------------------------------------


def _batch_work() -> None:
    """What the DSP pinger does between two round trips (untimed): build and encode a batch."""
    encode_batch(sample_batch(0, BATCH_SAMPLES))


def set_echo_hold(session: Any, key: str, hold_s: float, within_s: float = 10.0) -> None:
    """Set a zenoh echo's hold (``--hold-key``) and wait for its acknowledgement."""
    import queue

    acks: queue.SimpleQueue[str] = queue.SimpleQueue()
    text = f"{hold_s * 1e6:.3f}"
    sub = session.declare_subscriber(key + "/ack", lambda sample: acks.put(sample.payload.to_string()))
    try:
        deadline = time.monotonic() + within_s
        while time.monotonic() < deadline:
            session.put(key, text)
            try:
                if acks.get(timeout=0.2) == text:
                    return
            except queue.Empty:
                continue
        raise BenchError(f"the paced zenoh echo did not take its hold within {within_s:.0f} s")
    finally:
        sub.undeclare()


@dataclass(frozen=True)
class ZenohKeys:
    """The zenoh item's rig, ports and key expressions (all private to this run)."""

    rig_id: str
    echo_port: int
    paced_port: int
    dsp_port: int
    tls_port: int

    @property
    def ping(self) -> str:
        return f"ralf/{self.rig_id}/bench/ping"

    @property
    def pong(self) -> str:
        return f"ralf/{self.rig_id}/bench/pong"

    @property
    def paced_ping(self) -> str:
        return f"ralf/{self.rig_id}/bench/paced/ping"

    @property
    def paced_pong(self) -> str:
        return f"ralf/{self.rig_id}/bench/paced/pong"

    @property
    def hold_key(self) -> str:
        return f"ralf/{self.rig_id}/bench/paced/hold"

    @property
    def tls_ping(self) -> str:
        return f"ralf/{self.rig_id}/bench/tls/ping"

    @property
    def tls_pong(self) -> str:
        return f"ralf/{self.rig_id}/bench/tls/pong"


@dataclass
class ZenohPingers:
    """What the zenoh item times, and what it needs to summarise them."""

    pingers: list[Any]
    dp: DspPinger | None = None
    paced: ZenohPinger | None = None
    dsp_health: HealthWatch | None = None
    hold_s: float = 0.0


def bench_zenoh(ctx: BenchContext, result: dict[str, Any]) -> None:
    """Batch -> interrupt through the real DSP service vs bare zenoh and bare UDP ping-pong."""
    size = batch_size_bytes(BATCH_SAMPLES)
    keys = ZenohKeys(private_rig_id("zenoh"), *free_tcp_ports(4))
    result["config"] = {
        "rig_id": keys.rig_id,
        "payload_bytes": size,
        "batch": f"{BATCH_SAMPLES} samples, 2 inputs, 2 outputs, float64",
        "dsp": {"RALF_EMULATED_LATENCY_S": "0", "fft_width": DSP_FFT_WIDTH},
        "qos": "express=True, congestion_control=BLOCK, priority=REAL_TIME",
        "tls": "zenoh_pingpong_tls: mutual TLS (P-256 certificates of one authority), as ralf-hil up links its nodes",
        "iterations": ctx.iterations,
        "warmup": ctx.warmup,
    }
    with ExitStack() as stack:
        udp, zecho, dsp, paced_echo = _start_zenoh_peers(ctx, result, keys, stack)
        tls = _start_tls_echo(ctx, keys, stack)
        udp_port = int(udp.read_tagged("READY", 30)["port"])
        zecho.read_tagged("READY", 30)
        if paced_echo is not None:
            paced_echo.read_tagged("READY", 30)
        timed = _zenoh_pingers(ctx, result, keys, stack, size, udp_port, dsp)
        timed.pingers.append(_tls_pinger(keys, stack, size, tls))
        samples = _measure_pingers(ctx, timed.pingers)
        # the DSP's own timing of its interrupt's put, from its next health message (every batch of the run)
        dsp_h = timed.dsp_health.after(time.monotonic(), timeout_s=3.0) if timed.dp is not None and timed.dsp_health is not None else None
    _zenoh_measurements(result, samples, timed, dsp_h)


def _start_zenoh_peers(ctx: BenchContext, result: dict[str, Any], keys: ZenohKeys, stack: ExitStack) -> tuple[Child, Child, Child | None, Child | None]:
    """The UDP and zenoh echoes and, unless ``--floors-only``, the DSP service and the paced echo."""
    udp = stack.enter_context(Child.peer("udp-echo", log_dir=ctx.log_dir))
    zecho = stack.enter_context(
        Child.peer("zenoh-echo", "--listen", f"tcp/127.0.0.1:{keys.echo_port}", "--ping", keys.ping, "--pong", keys.pong, log_dir=ctx.log_dir)
    )
    dsp: Child | None = None
    paced_echo: Child | None = None
    if ctx.floors_only:
        result["notes"].append("--floors-only: the DSP service was not started")
        return udp, zecho, dsp, paced_echo
    try:
        requires("dsp_service.service")
        env = clean_env(
            {
                "RALF_RIG_ID": keys.rig_id,
                "RALF_ZENOH_MODE": "peer",
                "RALF_ZENOH_LISTEN": f"tcp/127.0.0.1:{keys.dsp_port}",
                "RALF_EMULATED_LATENCY_S": "0",
                "RALF_FFT_WIDTH": str(DSP_FFT_WIDTH),
                "RALF_BATCH_SIZE": str(BATCH_SAMPLES),
                "RALF_LOG_LEVEL": "WARNING",
            }
        )
        dsp = stack.enter_context(Child([sys.executable, "-m", "dsp_service"], env=env, name="dsp", log_dir=ctx.log_dir))
        paced_echo = stack.enter_context(
            Child.peer(
                "zenoh-echo",
                *("--listen", f"tcp/127.0.0.1:{keys.paced_port}", "--ping", keys.paced_ping, "--pong", keys.paced_pong, "--hold-key", keys.hold_key),
                name="zenoh-echo-paced",
                log_dir=ctx.log_dir,
            )
        )
    except Skip as exc:
        result["skipped"].append(f"dsp_batch_to_interrupt: {exc}")
    return udp, zecho, dsp, paced_echo


def _start_tls_echo(ctx: BenchContext, keys: ZenohKeys, stack: ExitStack) -> Path:
    """The zenoh echo again, over mutual TLS; returns the folder of its certificates."""
    from workbench.certificates import write_role_certificates

    folder = Path(tempfile.mkdtemp(prefix="tls-", dir=ctx.log_dir))  # a fresh owner-only folder
    write_role_certificates(folder, ("echo", "pinger"))
    echo = stack.enter_context(
        Child.peer(
            "zenoh-echo",
            *("--listen", f"tls/127.0.0.1:{keys.tls_port}", "--ping", keys.tls_ping, "--pong", keys.tls_pong, "--tls", str(folder)),
            name="zenoh-echo-tls",
            log_dir=ctx.log_dir,
        )
    )
    echo.read_tagged("READY", 30)
    return folder


def _tls_pinger(keys: ZenohKeys, stack: ExitStack, size: int, folder: Path) -> ZenohPinger:
    session = zenoh_session(connect=[f"tls/127.0.0.1:{keys.tls_port}"], tls=(str(folder / "ca.pem"), str(folder / "pinger.pem"), str(folder / "pinger.key")))
    stack.callback(session.close)
    pinger = ZenohPinger(session, keys.tls_ping, keys.tls_pong, size, name="zenoh_pingpong_tls")
    stack.callback(pinger.close)
    pinger.connect()
    return pinger


def _zenoh_pingers(ctx: BenchContext, result: dict[str, Any], keys: ZenohKeys, stack: ExitStack, size: int, udp_port: int, dsp: Child | None) -> ZenohPingers:
    """One session to every echo; the pingers in their timing order (DSP, zenoh, paced zenoh, UDP)."""
    endpoints = [f"tcp/127.0.0.1:{keys.echo_port}"] + ([f"tcp/127.0.0.1:{keys.dsp_port}", f"tcp/127.0.0.1:{keys.paced_port}"] if dsp else [])
    session = zenoh_session(connect=endpoints)
    stack.callback(session.close)
    zp = ZenohPinger(session, keys.ping, keys.pong, size)
    stack.callback(zp.close)
    up = UdpPinger(udp_port, size)
    stack.callback(up.close)
    zp.connect()
    timed = ZenohPingers([zp, up])
    if dsp is not None:
        _add_dsp_pinger(ctx, result, keys, stack, session, dsp, timed)
    if timed.dp is not None:
        # The same ping-pong paced as a DSP round trip: the echo holds its callback for the
        # DSP's step (its p50, busy) and the pinger builds a batch between round trips (untimed).
        try:
            paced = ZenohPinger(session, keys.paced_ping, keys.paced_pong, size, name="zenoh_pingpong_paced", prepare=_batch_work)
            stack.callback(paced.close)
            set_echo_hold(session, keys.hold_key, timed.hold_s)
            paced.connect()
            timed.pingers.insert(2, paced)
            timed.paced = paced
        except BenchError as exc:
            result["errors"].append(f"zenoh_pingpong_paced: {exc}")
    return timed


def _add_dsp_pinger(ctx: BenchContext, result: dict[str, Any], keys: ZenohKeys, stack: ExitStack, session: Any, dsp: Child, timed: ZenohPingers) -> None:
    """The DSP's pinger, its history filled once so every timed step is a full one; the
    step's median compute time becomes the paced echo's hold."""
    dp = DspPinger(session, keys.rig_id, samples=BATCH_SAMPLES)
    stack.callback(dp.close)
    timed.dsp_health = HealthWatch(session, Keys(keys.rig_id).health("dsp"))
    stack.callback(timed.dsp_health.close)
    try:
        ctx.say("  waiting for the DSP service's empty flag")
        dp.wait_empty(60.0, alive=dsp.alive)
        # fill the DSP's history once (N / l batches) so every timed step is a full one
        for _ in range(math.ceil(DSP_FFT_WIDTH / BATCH_SAMPLES) + 10):
            dp.once()
        timed.hold_s = float(np.median(dp.compute_s[-50:]))
        dp.compute_s.clear()
        dp.out_s.clear()
        dp.back_s.clear()
        dp.flag_wait_s.clear()
        timed.pingers.insert(0, dp)
        timed.dp = dp
        # the same step stand-alone in this process, interleaved: dsp_compute's floor in the same run
        from workbench.bench.dsp_step import StepPinger

        step = StepPinger(DSP_FFT_WIDTH, BATCH_SAMPLES, ctx.iterations + ctx.warmup)
        timed.pingers.insert(1, step)
        result["config"]["dsp"]["fft_form"] = step.fft_form
    except BenchError as exc:
        result["errors"].append(f"dsp_batch_to_interrupt: {exc}; {dsp.describe_failure()}")


def _zenoh_measurements(result: dict[str, Any], samples: dict[str, list[float]], timed: ZenohPingers, dsp_h: Any) -> None:
    """The zenoh item's measurements, in display order, each against its floor."""
    m = result["measurements"]
    udp_s = summarize(samples["udp_pingpong"])
    zen_s = summarize(samples["zenoh_pingpong"])
    dp, paced, hold_s = timed.dp, timed.paced, timed.hold_s
    if dp is not None:
        rtt = samples[dp.name]
        dsp_s = summarize(rtt)
        m["dsp_batch_to_interrupt"] = latency(dsp_s, "zenoh_pingpong", zen_s, vs_udp=ratios(dsp_s, udp_s))
        compute = dp.compute_s[-len(rtt) :]
        standalone = summarize(samples["dsp_step_standalone"]) if "dsp_step_standalone" in samples else None
        m["dsp_compute"] = latency(
            summarize(compute),
            *(("dsp_step_standalone", standalone) if standalone is not None else ()),
            note="Interrupt.compute_time_s: the identifier step inside the service, once per batch",
        )
        if standalone is not None:
            m["dsp_step_standalone"] = latency(standalone, note="the same batch append and step in the bench's process, back to back in blocks of 50")
        overhead = [max(r - c, 0.0) for r, c in zip(rtt, compute)]
        m["dsp_rtt_minus_compute"] = latency(
            summarize(overhead), "zenoh_pingpong", zen_s, note="round trip less the DSP's own compute time: transport + service overhead"
        )
        # the same round trip split at the interrupt's construction (Unix stamps of the batch and the interrupt)
        m["dsp_out_minus_compute"] = latency(
            summarize([max(x, 0.0) for x in dp.out_s[-len(rtt) :]]),
            note="batch put -> interrupt built, less the step: transport, the DSP's callback, batch decode, admission, the step's Python",
        )
        m["dsp_back"] = latency(summarize([max(x, 0.0) for x in dp.back_s[-len(rtt) :]]), note="interrupt built -> arrived here: encode, put, transport")
        put = dsp_h.latencies.get("interrupt_put") if dsp_h is not None else None
        if put is not None and put.count:
            m["dsp_interrupt_put"] = latency(
                from_latency_stats(put.model_dump()),
                note="the DSP's put of its interrupt (wall), from its health: zenoh sends the interrupt once the put returns; warm-up batches included",
            )
        else:
            result["notes"].append("no DSP health with its interrupt put's timing came within 3 s of the measurement")
        if paced is not None:
            paced_s = summarize(samples[paced.name])
            paced_floor = summarize([max(r - hold_s, 0.0) for r in samples[paced.name]])
            m["zenoh_pingpong_paced"] = latency(
                paced_s, note=f"the echo busy {hold_s * 1e6:.0f} us in its callback (the step's p50), a batch built between round trips"
            )
            m["zenoh_paced_minus_hold"] = latency(paced_floor, "zenoh_pingpong", zen_s, note="the paced ping-pong less the echo's hold")
            m["dsp_rtt_minus_compute_vs_paced"] = latency(
                summarize(overhead), "zenoh_paced_minus_hold", paced_floor, note="dsp_rtt_minus_compute against the paced ping-pong less its hold"
            )
        if dp.bad:
            result["notes"].append(f"{dp.bad} undecodable flag/interrupt payloads")
    m["zenoh_pingpong"] = latency(zen_s, "udp_pingpong", udp_s)
    if "zenoh_pingpong_tls" in samples:
        m["zenoh_pingpong_tls"] = latency(
            summarize(samples["zenoh_pingpong_tls"]), "zenoh_pingpong", zen_s, note="the same ping-pong over mutual TLS, as ralf-hil up links its nodes"
        )
    m["udp_pingpong"] = latency(udp_s)
    result["notes"].append("Round trips interleaved in blocks of 50 so a figure and its floors see the same machine state.")
    result["notes"].append(
        "zenoh arrivals are stamped in the subscriber callback (decoding and the hand-off to the measuring thread are not timed); UDP after recv()."
    )


# --- 2. CAN ---------------------------------------------------------------------------------------


def bench_can(ctx: BenchContext, result: dict[str, Any]) -> None:
    """SYNC -> TPDO1 through the plant node (lockstep) vs bare udp_multicast ping-pong."""
    rig_id = private_rig_id("can")
    floor_port = private_can_port(rig_id + "-floor")
    plant_port = private_can_port(rig_id)
    if plant_port == floor_port:
        plant_port += 1
    result["config"] = {
        "rig_id": rig_id,
        "interface": f"udp_multicast {CAN_GROUP}",
        "floor_port": floor_port,
        "plant_port": plant_port,
        "frames": "SYNC (1 byte) -> TPDO1 (8 bytes); floor: 8-byte request -> 8-byte reply",
        "plant": {"RALF_CLOCK": "lockstep", "RALF_WATCHDOG_PERIODS": "200"},
        "iterations": ctx.iterations,
        "warmup": ctx.warmup,
    }
    with ExitStack() as stack:
        echo = stack.enter_context(Child.peer("can-echo", "--channel", CAN_GROUP, "--port", str(floor_port), log_dir=ctx.log_dir))
        stock_port = floor_port + 2 if floor_port + 2 != plant_port else floor_port + 4
        stock_echo = stack.enter_context(
            Child.peer("can-echo", "--channel", CAN_GROUP, "--port", str(stock_port), "--bus", "stock", name="can-echo-stock", log_dir=ctx.log_dir)
        )
        plant = _start_can_plant(ctx, result, rig_id, plant_port, stack)
        echo.read_tagged("READY", 30)
        floor_bus = can_bus(floor_port, [0x181], CAN_GROUP)
        stack.callback(floor_bus.shutdown)
        cp = CanPinger(floor_bus)
        cp.connect()
        stock_echo.read_tagged("READY", 30)
        stock_bus = can_bus(stock_port, [0x181], CAN_GROUP, loop_free=False)
        stack.callback(stock_bus.shutdown)
        cp_stock = CanPinger(stock_bus)
        cp_stock.name = STOCK_PINGPONG
        cp_stock.connect()
        pingers: list[Any] = [cp, cp_stock]
        if plant is not None:
            from protocol import can_map

            ids = can_map.cob_ids(can_map.DEFAULT_NODE_ID)
            plant_bus = can_bus(plant_port, [ids["tpdo1"], ids["heartbeat"]], CAN_GROUP)
            stack.callback(plant_bus.shutdown)
            pp = PlantPinger(plant_bus)
            try:
                ctx.say("  waiting for the plant node's heartbeat")
                pp.start(60.0, alive=plant.alive)
                pingers.insert(0, pp)
            except BenchError as exc:
                result["errors"].append(f"plant_sync_to_tpdo: {exc}; {plant.describe_failure()}")
        samples = _measure_pingers(ctx, pingers)
    m = result["measurements"]
    floor = summarize(samples["can_pingpong"])
    if "plant_sync_to_tpdo" in samples:
        m["plant_sync_to_tpdo"] = latency(summarize(samples["plant_sync_to_tpdo"]), "can_pingpong", floor, note="includes one lockstep model step per SYNC")
    m["can_pingpong"] = latency(floor)
    stock = summarize(samples[STOCK_PINGPONG])
    m[STOCK_PINGPONG] = latency(stock, "can_pingpong", floor)
    if "plant_sync_to_tpdo" in samples:
        m["plant_sync_to_tpdo vs stock bus"] = latency(summarize(samples["plant_sync_to_tpdo"]), STOCK_PINGPONG, stock)
    result["notes"].append(
        "can_pingpong and the plant run on the rig's bus (service_kit/can_udp.py: own frames dropped in the kernel); "
        "the stock row is the same round trip on python-can's udp_multicast, which reads its own frames back and drops them (can_filters)."
    )
    junk_ports = private_can_port(rig_id + "-junk")
    blocks = max(20, min(200, ctx.iterations // 10))
    m.update(can_junk.rows(can_junk.measure(CAN_GROUP, tuple(junk_ports + 2 * k for k in range(5)), blocks), summarize, latency))
    result["notes"].append(f"can_junk_reject: per datagram, {blocks} blocks of {can_junk.BLOCK} (workbench/bench/can_junk.py), against a bare recvmsg.")


def _start_can_plant(ctx: BenchContext, result: dict[str, Any], rig_id: str, plant_port: int, stack: ExitStack) -> Child | None:
    """The plant service in lockstep on the item's own CAN port, unless ``--floors-only``."""
    if ctx.floors_only:
        result["notes"].append("--floors-only: the plant service was not started")
        return None
    try:
        requires("plant_emulator.service")
        env = clean_env(
            {
                "RALF_RIG_ID": rig_id,
                "RALF_ZENOH_MODE": "peer",
                "RALF_ZENOH_LISTEN": f"tcp/127.0.0.1:{free_tcp_port()}",
                "RALF_CAN_INTERFACE": "udp_multicast",
                "RALF_CAN_CHANNEL": CAN_GROUP,
                "RALF_CAN_PORT": str(plant_port),
                "RALF_CLOCK": "lockstep",
                "RALF_WATCHDOG_PERIODS": "200",
                "RALF_LOG_LEVEL": "WARNING",
            }
        )
        return stack.enter_context(Child([sys.executable, "-m", "plant_emulator"], env=env, name="plant", log_dir=ctx.log_dir))
    except Skip as exc:
        result["skipped"].append(f"plant_sync_to_tpdo: {exc}")
        return None


# --- shared: short floors and a whole rig ------------------------------------------------------------


STOCK_PINGPONG = "can_pingpong (python-can stock bus)"


def can_floor(ctx: BenchContext, iterations: int, period_s: float = 0.0) -> dict[str, Any]:
    """A short bare udp_multicast ping-pong on the rig's bus (the floor of one
    control tick); with ``period_s`` its round trips start that far apart, as
    a real-time loop's ticks do (:class:`PacedPinger`)."""
    port = private_can_port(private_rig_id("canfloor"))
    with ExitStack() as stack:
        echo = stack.enter_context(Child.peer("can-echo", "--channel", CAN_GROUP, "--port", str(port), log_dir=ctx.log_dir))
        echo.read_tagged("READY", 30)
        bus = can_bus(port, [0x181], CAN_GROUP)
        stack.callback(bus.shutdown)
        cp = CanPinger(bus)
        cp.connect()
        pinger: CanPinger | PacedPinger = PacedPinger(cp, period_s) if period_s > 0 else cp
        return summarize(interleave([pinger], iterations, min(ctx.warmup, 50))[pinger.name])


def sleep_floor(ctx: BenchContext, rate_hz: float, seconds: float) -> dict[str, Any]:
    rt = ("--rt-priority", str(ctx.rt_priority), "--cpu-affinity", ctx.cpu_affinity, "--cpu-latency-us", str(ctx.rt_cpu_latency_us))
    with Child.peer("sleep-jitter", "--rate", str(rate_hz), "--seconds", str(seconds), *rt, name=f"sleep-jitter-{rate_hz:g}", log_dir=ctx.log_dir) as child:
        return child.read_tagged("RESULT", seconds + 30)


def listen_config(port: int) -> Any:
    import zenoh

    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    return config


def run_rig(
    ctx: BenchContext,
    rig_id: str,
    clock: str,
    common: Mapping[str, str],
    overrides: Mapping[str, Mapping[str, str]],
    stop_after_running_s: float | None,
    timeout_s: float,
) -> dict[str, Any]:
    """The three services as local processes (workbench.launcher), watched on zenoh.

    Ends when the controller exits, or ``stop_after_running_s`` after its
    first tick; always stops every service. Returns the statuses with their
    arrival times, the last snapshot (health, liveliness) and exit codes.
    """
    from workbench.launcher import RigPlan, supervise
    from workbench.monitor import RigWatch

    plan = RigPlan.local(rig_id=rig_id, clock=clock, overrides=overrides, common=common)
    log_dir = ctx.log_dir / rig_id
    out: dict[str, Any] = {"failure": None, "exit_codes": {}, "log_dir": str(log_dir)}
    watch = RigWatch(rig_id, listen_config(plan.zenoh_port), history=True)

    def latest() -> Any:
        history = watch.history()
        return history[-1][1] if history else None

    try:
        sup = supervise(plan, log_dir, latest, run_for_s=stop_after_running_s, timeout_s=timeout_s, poll_s=0.1)
        out["failure"] = sup.failure or None
        out["exit_codes"] = sup.exit_codes
        out["startup_s"] = sup.startup_s
        time.sleep(0.3)
        out["snapshot"] = watch.snapshot()
        out["history"] = watch.history()
    finally:
        watch.close()
    if out["failure"]:
        out["logs"] = {name: tail(p.log_path, 6) for name, p in sup.procs.items()}
    return out


def _progress(history: list[tuple[float, Any]]) -> dict[str, float] | None:
    """Ticks per wall second and simulated seconds per wall second between
    the first status after the first tick and the last status."""
    running = [(t, s) for t, s in history if s.ticks > 0]
    if len(running) < 2:
        return None
    (t0, s0), (t1, s1) = running[0], running[-1]
    span = t1 - t0
    if span <= 0:
        return None
    return {"ticks_per_s": (s1.ticks - s0.ticks) / span, "sim_per_wall": (s1.sim_time_s - s0.sim_time_s) / span, "wall_s": span, "ticks": s1.ticks}


# --- 3. real time -------------------------------------------------------------------------------------


BURN_LIMIT_S = 3600.0
"""A CPU burner ends by itself after this long even if the bench could not stop it."""


@contextmanager
def cpu_burners(n: int) -> Iterator[list[subprocess.Popen[bytes]]]:
    """``n`` CPU-burning processes (a loaded host), each bounded in time, killed by PID on exit."""
    code = f"import time\nend = time.monotonic() + {BURN_LIMIT_S}\nwhile time.monotonic() < end:\n    pass\n"
    procs = [subprocess.Popen([sys.executable, "-c", code]) for _ in range(n)]
    try:
        yield procs
    finally:
        for p in procs:
            p.kill()
        for p in procs:
            p.wait(timeout=10)


def bench_realtime(ctx: BenchContext, result: dict[str, Any]) -> None:
    """The whole rig in real time at each rate (``ctx.rates``, default 200 Hz and
    1 kHz for ``duration_s``; 200 Hz alone with ``quick``), optionally with CPU burners running."""
    requires("plant_emulator.service", "controller.service", "dsp_service.service")
    m = result["measurements"]
    runs = ctx.rates or (((200.0, None),) if ctx.quick else ((200.0, None), (1000.0, None)))
    result["config"] = {
        "duration_s": ctx.duration_s,
        "rates_hz": [r for r, _ in runs],
        "batch_period_s": ctx.batch_period_s,
        "burners": ctx.burners,
        "rt_priority": ctx.rt_priority,
        "cpu_affinity": ctx.cpu_affinity,
        "rt_cpu_latency_us": ctx.rt_cpu_latency_us,
        "runs": {},
    }
    for rate, seconds in runs:
        plan = _realtime_plan(ctx, rate, seconds if seconds is not None else ctx.duration_s)
        result["config"]["runs"][plan.tag] = plan.config()
        try:
            floors, run = _realtime_floors_and_rig(ctx, result, plan)
        except BenchError as exc:
            result["errors"].append(f"{plan.tag}: {exc}")
            continue
        _realtime_measurements(result, plan, floors, run)
    result["notes"].append(
        "batch_to_interrupt is the controller's own figure: from publishing a batch to its interrupt arriving (stamped in the zenoh callback), emulated latency included."
    )
    if not m:
        result["status"] = "failed"


@dataclass(frozen=True)
class RealtimePlan:
    """One rate of the real-time item: the rig's settings and where its record goes."""

    rate: float
    duration: float
    batch: int
    latency_s: float
    rig_id: str
    common: dict[str, str]
    overrides: dict[str, dict[str, str]]
    record: Path

    @property
    def tag(self) -> str:
        return f"{self.rate:g}Hz"

    def config(self) -> dict[str, Any]:
        return {
            "rig_id": self.rig_id,
            "duration_s": self.duration,
            "batch_size": self.batch,
            "batch_period_s": self.batch / self.rate,
            "emulated_latency_s": self.latency_s,
            "env": {**self.common, **{f"{k}.{n}": v for k, d in self.overrides.items() for n, v in d.items()}},
        }


def _realtime_plan(ctx: BenchContext, rate: float, duration: float) -> RealtimePlan:
    batch = max(1, round(ctx.batch_period_s * rate))  # batch period > the DSP's emulated latency: the deadline has slack
    latency_s = 0.1
    rig_id = private_rig_id(f"rt{rate:g}")
    common = {"RALF_SAMPLE_RATE_HZ": str(rate), "RALF_HEALTH_PERIOD_S": "0.5"}
    measures = {"priority": ctx.rt_priority, "cpus": ctx.cpu_affinity, "cpu_latency_us": ctx.rt_cpu_latency_us}
    common["RALF_REALTIME"] = json.dumps(measures)
    record = ctx.log_dir / rig_id / "controller-record"
    overrides = {
        "controller": {"RALF_DURATION_S": str(duration), "RALF_BATCH_SIZE": str(batch), "RALF_RUN_RECORD": str(record)},
        "dsp": {"RALF_BATCH_SIZE": str(batch), "RALF_EMULATED_LATENCY_S": str(latency_s)},
    }
    return RealtimePlan(rate, duration, batch, latency_s, rig_id, common, overrides, record)


@dataclass(frozen=True)
class RealtimeFloors:
    """What the same host does without the rig, measured just before it: a sleep-only loop and bare CAN ping-pongs."""

    sleep: dict[str, Any]
    can: dict[str, Any]
    can_paced: dict[str, Any]


def _realtime_floors_and_rig(ctx: BenchContext, result: dict[str, Any], plan: RealtimePlan) -> tuple[RealtimeFloors, dict[str, Any]]:
    """The floors, then the three-process rig, with the CPU burners (if any) running throughout."""
    tag, duration = plan.tag, plan.duration
    with cpu_burners(ctx.burners):
        floor_s = min(duration, ctx.floor_s)
        ctx.say(f"  {tag}: floors (sleep-to-deadline loop for {floor_s:g} s, bare CAN ping-pong)" + (f", {ctx.burners} CPU burners" if ctx.burners else ""))
        sleep = sleep_floor(ctx, plan.rate, floor_s)
        result["notes"].append(f"{tag}: the sleep-only floor ran with {sleep.get('realtime', 'the normal scheduler')}")
        canf = can_floor(ctx, max(200, ctx.iterations // 2))
        canf_paced = can_floor(ctx, 200, 1.0 / plan.rate)
        ctx.say(f"  {tag}: three-process rig for {duration:g} s")
        run = run_rig(ctx, plan.rig_id, "realtime", plan.common, plan.overrides, None, duration + 90)
    return RealtimeFloors(sleep, canf, canf_paced), run


def _realtime_measurements(result: dict[str, Any], plan: RealtimePlan, floors: RealtimeFloors, run: dict[str, Any]) -> None:
    """One rate's measurements, each against the floor of the same run, then its verdict and notes."""
    m = result["measurements"]
    tag, rate, latency_s, record = plan.tag, plan.rate, plan.latency_s, plan.record
    sleep, canf, canf_paced = floors.sleep, floors.can, floors.can_paced
    result["config"]["runs"][tag].update(exit_codes=run["exit_codes"], log_dir=run["log_dir"])
    if run["failure"]:
        result["errors"].append(f"{tag}: {run['failure']}; logs: {run.get('logs')}")
    ctrl = run["snapshot"]["services"]["controller"]["health"]
    progress = _progress(run["history"])
    if progress is None or ctrl is None:
        result["errors"].append(f"{tag}: no controller status/health received")
        return
    status = run["history"][-1][1]
    lat, counters = ctrl["latencies"], ctrl["counters"]
    m[f"{tag} loop_rate"] = scalar(
        progress["ticks_per_s"], "Hz", "nominal", rate, ticks=progress["ticks"], over_wall_s=progress["wall_s"], status_loop_rate_hz=status.loop_rate_hz
    )
    m[f"{tag} sleep_jitter (floor)"] = latency(sleep["jitter"], note="a process that only sleeps to t0 + k/rate")
    m[f"{tag} sync_jitter"] = latency(from_latency_stats(lat["sync_jitter"]), f"{tag} sleep_jitter (floor)", sleep["jitter"])
    timing = _timing_record(record)
    if timing is not None:
        _timing_measurements(m, result["notes"], tag, timing, 1.0 / rate, sleep)
    else:
        result["notes"].append(f"{tag}: no controller timing record at {record}.timing.npz (SYNC period jitter not computed)")
    m[f"{tag} can_pingpong (floor)"] = latency(canf)
    m[f"{tag} tet"] = latency(from_latency_stats(lat["tet"]), f"{tag} can_pingpong (floor)", canf, note="SYNC to the end of the tick")
    for hop, note in (("sync_to_tpdo", "SYNC sent -> TPDO1 received: CAN out, the plant, CAN back"), ("tick_compute", "TPDO1 -> tick done")):
        if lat.get(f"hop_{hop}", {}).get("count"):
            m[f"{tag} tet: {hop}"] = latency(from_latency_stats(lat[f"hop_{hop}"]), f"{tag} can_pingpong (floor)", canf, note=note)
    paced_name = f"{tag} can_pingpong paced at the loop's period (floor)"
    m[paced_name] = latency(canf_paced, note="the same ping-pong, each round trip started one period after the last (the CPUs idle between, as the loop's)")
    if lat.get("hop_sync_to_tpdo", {}).get("count"):
        m[f"{tag} tet: sync_to_tpdo vs paced"] = latency(from_latency_stats(lat["hop_sync_to_tpdo"]), paced_name, canf_paced)
    if lat["batch_to_interrupt"]["count"]:
        m[f"{tag} batch_to_interrupt"] = latency_vs_value(
            from_latency_stats(lat["batch_to_interrupt"]), f"emulated latency {latency_s * 1e3:g} ms", latency_s * 1e6
        )
    else:
        result["errors"].append(f"{tag}: no interrupt came back from the DSP")
    sleep_per_tick = _realtime_counts(m, tag, status, counters, sleep)
    dsp_h = run["snapshot"]["services"]["dsp"]["health"]
    if dsp_h and dsp_h["latencies"].get("compute", {}).get("count"):
        m[f"{tag} dsp_compute"] = latency(from_latency_stats(dsp_h["latencies"]["compute"]), note="DSP's identifier step, from its health")
    result["config"]["runs"][tag]["controller_counters"] = counters
    _realtime_verdict(result, tag, ctrl, counters, sleep_per_tick)
    if progress["ticks_per_s"] < 0.98 * rate or lat["sync_jitter"]["p50"] > 1.0 / rate:
        result["notes"].append(
            f"{tag}: the loop fell behind its absolute schedule t0 + k*Ts ({progress['ticks_per_s']:.0f} of {rate:g} ticks/s); "
            "sync_jitter then measures accumulated lateness, not per-tick jitter"
        )


def _realtime_counts(m: dict[str, Any], tag: str, status: Any, counters: Mapping[str, Any], sleep: Mapping[str, Any]) -> float:
    """Overruns (against the sleep loop's), TPDO timeouts and deadline misses; returns the sleep loop's overruns per tick."""
    ticks = max(int(status.ticks), 1)
    overruns = int(counters.get("overruns", status.overruns))
    m[f"{tag} overruns"] = scalar(overruns, "ticks", "sleep loop's overruns", sleep["overruns"], per_tick=overruns / ticks, ticks=ticks)
    sleep_per_tick: float = sleep["overruns"] / max(int(sleep.get("ticks", 1)), 1)
    m[f"{tag} overruns per tick"] = scalar(
        overruns / ticks,
        "per tick",
        "sleep loop's overruns per tick",
        sleep_per_tick if sleep_per_tick > 0 else None,
        sleep_overruns=sleep["overruns"],
        sleep_ticks=sleep.get("ticks"),
        note="target (1 kHz, idle host): at most 2x the sleep loop's",
    )
    m[f"{tag} tpdo_timeouts"] = scalar(
        int(counters.get("tpdo_timeouts", 0)), "ticks", None, None, note="no TPDO within 0.8 Ts of the SYNC: the last sample was held"
    )
    m[f"{tag} deadline_misses"] = scalar(
        int(counters.get("deadline_misses", status.deadline_misses)), "batches", None, None, batches_sent=status.batches_sent, interrupts=status.interrupts
    )
    return sleep_per_tick


def _realtime_verdict(result: dict[str, Any], tag: str, ctrl: dict[str, Any], counters: Mapping[str, Any], sleep_per_tick: float) -> None:
    """The same criteria as `up` and `timing-test` (docs/timing-faults.md), the overruns against this run's sleep-only loop."""
    verdict = health_verdict(ctrl, overrun_floor_per_tick=sleep_per_tick)
    latency_line = latency_class(ctrl, host_info())
    if latency_line:
        result["config"]["runs"][tag]["host_latency_class"] = latency_line
        result["notes"].append(f"{tag}: host latency class (information) {latency_line}")
    if verdict:
        result["config"]["runs"][tag]["verdict"] = verdict
        result["notes"].append(f"{tag}: timing verdict {verdict}")
    rt = {k: v for k, v in counters.items() if k.startswith("rt_")}
    if rt:
        result["notes"].append(f"{tag}: real-time measures in effect in the controller: {rt}")


def _timing_record(record: Path) -> dict[str, Any] | None:
    """The controller's per-tick timing (RALF_RUN_RECORD): tick, sync_wall_s, tet_s, and its settings."""
    import numpy as np

    npz = Path(str(record) + ".timing.npz")
    if not npz.exists():
        return None
    with np.load(npz, allow_pickle=False) as data:
        out: dict[str, Any] = {name: np.asarray(data[name]) for name in ("tick", "sync_wall_s", "tet_s")}
    try:
        out["config"] = json.loads(Path(str(record) + ".json").read_text())["config"]
    except (OSError, ValueError, KeyError):
        out["config"] = {}
    return out


def _timing_measurements(m: dict[str, Any], notes: list[str], tag: str, timing: Mapping[str, Any], ts: float, sleep: Mapping[str, Any]) -> None:
    """SYNC period jitter (|interval - Ts|, the CANopen sense) beside the sleep loop's,
    the worst SYNC intervals, and the TET of the ticks that download transfer functions."""
    import numpy as np

    starts, tet, ticks = timing["sync_wall_s"], timing["tet_s"], timing["tick"]
    if starts.size < 3:
        return
    intervals = np.diff(starts)
    m[f"{tag} sync_period_jitter"] = latency(
        summarize(np.abs(intervals - ts)),
        f"{tag} sleep_period_jitter (floor)",
        sleep["period_jitter"],
        note="|SYNC interval - Ts| from the controller's timing record",
    )
    m[f"{tag} sleep_period_jitter (floor)"] = latency(sleep["period_jitter"])
    worst = np.argsort(intervals)[-3:][::-1]
    notes.append(f"{tag}: longest SYNC intervals " + ", ".join(f"{intervals[i] * 1e3:.1f} ms before tick {int(ticks[i + 1])}" for i in worst))
    every = int(timing["config"].get("tf_download_samples") or 0)
    if every:
        at = (ticks > 0) & (ticks % every == 0)
        if at.any():
            m[f"{tag} tet at TF-download ticks"] = latency(
                summarize(tet[at]), "tet of the other ticks", summarize(tet[~at]), note=f"ticks that also download transfer functions (every {every} samples)"
            )


# --- 4. lockstep --------------------------------------------------------------------------------------


def bench_lockstep(ctx: BenchContext, result: dict[str, Any]) -> None:
    """Simulated seconds per wall second: three processes, and one process if workbench.composition exists."""
    requires("plant_emulator.service", "controller.service", "dsp_service.service")
    m = result["measurements"]
    rate = 200.0
    ctx.say("  floor: bare CAN ping-pong (a lockstep tick needs at least one)")
    canf = can_floor(ctx, max(200, ctx.iterations // 2))
    ceiling = (1.0 / rate) / (canf["p50_us"] * 1e-6)
    rig_id = private_rig_id("lock")
    overrides = {"controller": {"RALF_DURATION_S": "3600"}}
    result["config"] = {
        "rig_id": rig_id,
        "rate_hz": rate,
        "wall_s": ctx.duration_s,
        "controller": {"RALF_DURATION_S": "3600 (stopped after the wall time)"},
        "dsp_emulated_latency_s": "default (0.1 s simulated)",
    }
    ctx.say(f"  three-process rig in lockstep for {ctx.duration_s:g} s")
    run = run_rig(ctx, rig_id, "lockstep", {"RALF_HEALTH_PERIOD_S": "0.5"}, overrides, ctx.duration_s, ctx.duration_s + 90)
    result["config"]["exit_codes"] = run["exit_codes"]
    if run["failure"]:
        result["errors"].append(f"three-process: {run['failure']}; logs: {run.get('logs')}")
    progress = _progress(run["history"])
    three: float | None = None
    m["can_pingpong (floor)"] = latency(canf)
    if progress is None:
        result["errors"].append("three-process: no controller progress seen")
    else:
        three = progress["sim_per_wall"]
        m["three_process sim_s/wall_s"] = scalar(
            three, "x", "CAN-bound ceiling (one bare round trip per tick)", ceiling, ticks_per_s=progress["ticks_per_s"], over_wall_s=progress["wall_s"]
        )
        ctrl = run["snapshot"]["services"]["controller"]["health"]
        if ctrl:
            m["three_process tet"] = latency(
                from_latency_stats(ctrl["latencies"]["tet"]), "can_pingpong (floor)", canf, note="wall time per lockstep tick, SYNC to end of tick"
            )
            # where the tick goes: SYNC -> TPDO1 (CAN out, the plant, CAN back), then the controller's tick
            for hop, note in (("sync_to_tpdo", "SYNC sent -> TPDO1 received"), ("tick_compute", "TPDO1 -> tick done")):
                if ctrl["latencies"].get(f"hop_{hop}", {}).get("count"):
                    m[f"three_process {hop}"] = latency(from_latency_stats(ctrl["latencies"][f"hop_{hop}"]), "can_pingpong (floor)", canf, note=note)
    _bench_cosim(ctx, result, three)
    try:
        requires("workbench.composition")
    except Skip as exc:
        result["skipped"].append(f"one_process: {exc}")
        return
    comp = importlib.import_module("workbench.composition")
    if not hasattr(comp, "run_in_process"):
        result["skipped"].append("one_process: workbench.composition has no run_in_process yet")
        return
    sim_s = max(2.0, min(600.0, (three or 5.0) * ctx.duration_s))
    ctx.say(f"  one-process composition: {sim_s:.0f} s simulated")
    try:
        with Child.peer("composition", "--sim-s", f"{sim_s:.3f}", log_dir=ctx.log_dir) as child:
            out = child.read_tagged("RESULT", ctx.duration_s * 10 + 120)
    except BenchError as exc:
        result["errors"].append(f"one_process: {exc}")
        return
    if out.get("error"):
        result["errors"].append(f"one_process: run ended with {out['error']}")
    one = out["sim_time_s"] / out["wall_time_s"] if out["wall_time_s"] > 0 else None
    m["one_process sim_s/wall_s"] = scalar(
        one, "x", "three-process", three, sim_time_s=out["sim_time_s"], wall_time_s=out["wall_time_s"], note="wall time includes the run's start-up"
    )
    m["one_process tet"] = latency(from_latency_stats(out["tet"]), "can_pingpong (floor)", canf, note="virtual bus in one process: no socket round trip")


COSIM_TARGET = 100.0
"""The co-simulation should run the default loop at least this many times faster than real time."""


def _bench_cosim(ctx: BenchContext, result: dict[str, Any], three: float | None) -> None:
    """The direct co-simulation (workbench.cosim) of the default loop (default settings), in this process."""
    try:
        requires("workbench.cosim")
    except Skip as exc:
        result["skipped"].append(f"cosim: {exc}")
        return
    from workbench.cosim import run_cosim

    sim_s = 10.0 if ctx.quick else 60.0
    ctx.say(f"  co-simulation of the default loop: {sim_s:.0f} s simulated, one thread")
    run = run_cosim(controller={"duration_s": sim_s})
    if run.result.error:
        result["errors"].append(f"cosim: run ended with {run.result.error}")
    rate = run.result.sim_time_s / run.wall_time_s if run.wall_time_s > 0 else None
    m = result["measurements"]
    m["cosim sim_s/wall_s"] = scalar(
        rate, "x", "target", COSIM_TARGET, sim_time_s=run.result.sim_time_s, wall_time_s=run.wall_time_s, note="wall time includes start-up"
    )
    if three:
        m["cosim vs three_process"] = scalar(rate, "x", "three_process sim_s/wall_s", three)
    m["cosim tet"] = latency(
        from_latency_stats(run.controller.tet.stats().model_dump()),
        note="wall time per co-simulated tick: plant step, controller tick, codecs (the DSP step in its batch's tick)",
    )


def _cosim_floor(ctx: BenchContext, m: dict[str, Any], sim_s: float) -> None:
    """The co-simulation's wall time per tick against its models alone, replayed
    with the run's own inputs (:mod:`workbench.bench.model_floor`), in alternating rounds."""
    from workbench.bench.model_floor import floor_report

    rounds = 2 if ctx.quick else 3
    ctx.say(f"  the models alone over the same {sim_s:.0f} s (recorded inputs replayed), {rounds} rounds alternating with the co-simulation")
    floor = floor_report({"duration_s": sim_s}, rounds=rounds)
    m["cosim per tick vs the models alone"] = scalar(
        floor["cosim_us"],
        "us",
        "plant model + control law + DSP step, replayed alone",
        floor["models_us"],
        note="best of alternating rounds; the co-simulation's wall time includes its start-up",
        rounds=floor["rounds"],
    )
    for key, name in (("plant_us", "plant model step"), ("law_us", "control law tick"), ("dsp_us", "DSP core, amortized per tick")):
        m[f"  models alone: {name}"] = scalar(floor[key], "us")


def bench_cosim(ctx: BenchContext, result: dict[str, Any]) -> None:
    """The co-simulation alone: simulated s per wall s and per CPU s against the
    100x target, µs per tick, and where a tick goes (:mod:`workbench.bench.cosim_parts`)."""
    import os

    requires("workbench.cosim")
    from workbench.bench.cosim_parts import cosim_parts
    from workbench.cosim import run_cosim

    sim_s = 10.0 if ctx.quick else 60.0
    ctx.say(f"  co-simulation of the default loop: {sim_s:.0f} s simulated, one thread (after a 1 s warm-up)")
    run_cosim(controller={"duration_s": 1.0})
    cpu = time.process_time()
    run = run_cosim(controller={"duration_s": sim_s})
    cpu = time.process_time() - cpu
    if run.result.error:
        result["errors"].append(f"cosim: run ended with {run.result.error}")
    ticks = max(run.result.ticks, 1)
    m = result["measurements"]
    m["cosim sim_s/wall_s"] = scalar(
        run.result.sim_time_s / run.wall_time_s,
        "x",
        "target",
        COSIM_TARGET,
        sim_time_s=run.result.sim_time_s,
        wall_time_s=run.wall_time_s,
        note="wall time includes start-up",
    )
    m["cosim sim_s/cpu_s"] = scalar(
        run.result.sim_time_s / cpu if cpu > 0 else None, "x", "target", COSIM_TARGET, cpu_s=cpu, note="process CPU time: what the run costs on a shared host"
    )
    tick_budget_us = 1e6 / 200.0 / COSIM_TARGET
    m["cosim wall per tick"] = scalar(run.wall_time_s / ticks * 1e6, "us", "100x budget", tick_budget_us)
    m["cosim cpu per tick"] = scalar(cpu / ticks * 1e6, "us", "100x budget", tick_budget_us)
    _cosim_floor(ctx, m, sim_s)
    parts = cosim_parts(5.0 if ctx.quick else 20.0)
    result["parts"] = parts
    for name, us in parts["parts_us_per_tick"].items():
        m[f"  {name}"] = scalar(us, "us", "100x budget", tick_budget_us, share=parts["parts_share"][name])
    result["config"] = {
        "sim_s": sim_s,
        "controller": "default loop (default settings)",
        "parts_sim_s": 5.0 if ctx.quick else 20.0,
        "load_average": os.getloadavg(),
    }
    result["notes"].append(
        "cosim parts: instrumented run (perf_counter wrappers, adaptive OATF), inclusive wall µs per tick; the service's share is the rest of the run"
    )


# --- 5. DSP -------------------------------------------------------------------------------------------


def bench_dsp(ctx: BenchContext, result: dict[str, Any]) -> None:
    """workbench.bench.dsp_step.bench_identifier(n=2048) against its numpy floor and the C40's 100 ms."""
    requires("dsp_service.identifier")
    from workbench.bench import dsp_step as module

    repeats = 30 if ctx.quick else 200
    ctx.say(f"  bench_identifier(n=2048, repeats={repeats})")
    raw = module.bench_identifier(n=2048, repeats=repeats)
    result["raw"] = raw
    result["config"] = {"n": 2048, "repeats": repeats}
    step = {"n": raw["repeats"], "p50_us": raw["step_p50_us"], "p99_us": raw["step_p99_us"]}
    floor = {"n": raw["repeats"], "p50_us": raw["floor_p50_us"], "p99_us": raw["floor_p99_us"]}
    m = result["measurements"]
    m["identifier_step"] = latency(step, "numpy_floor", floor, poles_found=raw.get("poles_found"))
    m["numpy_floor"] = latency(floor, note="4 rfft + 8 cross-spectra, bare numpy: one batched FFT, one broadcast multiply, preallocated outputs")
    if raw.get("floor_products_p50_us"):
        products = {"n": raw["repeats"], "p50_us": raw["floor_products_p50_us"], "p99_us": raw["floor_products_p99_us"]}
        m["numpy_floor_products"] = latency(products, note="the same floor with eight separate conj(X_a)*X_b products (the headline floor before)")
        m["identifier_step vs products floor"] = latency(step, "numpy_floor_products", products)
    if raw.get("floor_unbatched_p50_us"):
        m["numpy_floor_unbatched"] = latency(
            {"n": raw["repeats"], "p50_us": raw["floor_unbatched_p50_us"]}, note="the same floor without batching the FFTs (see workbench.bench.dsp_step)"
        )
    m["identifier_step vs C40"] = scalar(raw["step_p50_us"], "us", "C40 100 ms", module.C40_STEP_US)
    if hasattr(module, "bench_stages"):
        stages = module.bench_stages(n=2048, repeats=repeats)
        result["stages"] = stages
        ctx.say(
            "  stages of the compiled step (p50 us, / floor): "
            + ", ".join(
                f"{k} {stages[k]:.1f} ({stages[k] / stages['floor']:.2f})"
                for k in ("detrend", "fft", "average", "solve", "smooth", "peaks", "poles", "python", "step")
            )
        )
    if hasattr(module, "bench_sizes"):
        rows = module.bench_sizes(repeats=repeats)
        result["sizes"] = rows
        for line in module.format_report(rows, result.get("stages") or {}).splitlines()[: len(rows) + 1]:
            ctx.say("  " + line)
        for r in rows:
            m[f"identifier_step N={r['n']}"] = latency(
                {"n": r["repeats"], "p50_us": r["step_p50_us"], "p99_us": r["step_p99_us"]},
                "numpy_floor",
                {"n": r["repeats"], "p50_us": r["floor_p50_us"], "p99_us": r["floor_p99_us"]},
            )
        big = rows[-1]
        # a 1 kHz loop sends a batch at least every 1 ms: the step must fit in that period
        m[f"identifier_step N={big['n']} vs 1 kHz"] = latency_vs_value(
            {"n": big["repeats"], "p50_us": big["step_p50_us"], "p99_us": big["step_p99_us"]}, "1 ms (1 kHz batch period, l = 1)", 1000.0
        )


def bench_hotpath(ctx: BenchContext, result: dict[str, Any]) -> None:
    """Controller tick and plant step in a micro-benchmark (workbench.bench.hotpath) against the 100 µs target and CAN ping-pong."""
    from workbench.bench import hotpath

    n = 500 if ctx.quick else 3000
    ctx.say(f"  controller tick and plant step, {n} calls each, and their parts")
    raw = hotpath.bench_hotpath(n=n, warmup=100)
    result["config"] = {"n": n, "oatf_mode": "adaptive", "target_us": hotpath.TARGET_US}
    m = result["measurements"]
    for name, stats in raw.items():
        m[name.strip()] = latency_vs_value(stats, "100 µs target", hotpath.TARGET_US) if not name.startswith(" ") else latency(stats)


def bench_dsp_rigs(ctx: BenchContext, result: dict[str, Any]) -> None:
    """How many 200 Hz rigs one DSP process serves (:mod:`workbench.bench.dsp_rigs`)."""
    requires("dsp_service.service")
    from workbench.bench.dsp_rigs import bench_dsp_rigs as run

    run(ctx, result)


def bench_runs(ctx: BenchContext, result: dict[str, Any]) -> None:
    """Co-simulated runs per second, start-up included, on one core and on the local cluster (:mod:`workbench.bench.run_rate`)."""
    from workbench.bench.run_rate import bench_runs as run

    run(ctx, result)


def bench_fmu(ctx: BenchContext, result: dict[str, Any]) -> None:
    """The FMU plant's step against the built-in arm's, and the co-simulation's speed with it (:mod:`workbench.bench.fmu_plant`)."""
    from workbench.bench.fmu_plant import bench_fmu as run

    run(ctx, result)


def bench_can_wire(ctx: BenchContext, result: dict[str, Any]) -> None:
    """The simulated CAN wire's cost per frame against the same co-simulation without it (:mod:`workbench.bench.can_wire_cost`)."""
    from workbench.bench.can_wire_cost import bench_can_wire as run

    run(ctx, result)


ITEMS: dict[str, Callable[[BenchContext, dict[str, Any]], None]] = {
    "zenoh": bench_zenoh,
    "can": bench_can,
    "realtime": bench_realtime,
    "lockstep": bench_lockstep,
    "cosim": bench_cosim,
    "runs": bench_runs,
    "dsp": bench_dsp,
    "dsp-rigs": bench_dsp_rigs,
    "hotpath": bench_hotpath,
    "fmu": bench_fmu,
    "can-wire": bench_can_wire,
}
FLOOR_ITEMS = ("zenoh", "can")
QUICK_ITEMS = ("zenoh", "can", "realtime", "cosim", "hotpath")
"""``bench --quick``: the floors, one 200 Hz real-time rig beside them, the co-simulation and the hot path (the rest with --only)."""


def run_item(name: str, ctx: BenchContext) -> dict[str, Any]:
    """Run one item; a failure or a missing dependency is reported, never raised."""
    result = new_result()
    started = time.monotonic()
    try:
        ITEMS[name](ctx, result)
    except Skip as exc:
        result["status"] = "skipped"
        result["skipped"].append(str(exc))
    except Exception as exc:  # report, keep going with the next item
        result["errors"].append(f"{type(exc).__name__}: {exc}")
    if result["status"] != "skipped":
        if not result["errors"] and not result["measurements"]:  # an item that measured nothing is not ok
            result["errors"].append("no measurement made")
        if result["errors"]:
            result["status"] = "failed"
        elif result["skipped"]:
            result["status"] = "partial"
    result["wall_s"] = round(time.monotonic() - started, 3)
    return result
