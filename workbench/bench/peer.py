"""Helper processes of the bench: the far end of each floor measurement,
and measurements that must run in a process of their own.

``python -m workbench.bench.peer MODE ...``, MODE one of:

* ``udp-echo``: bare UDP echo on a loopback port of its own;
* ``zenoh-echo``: zenoh peer that republishes every ping on the pong key
  (express, BLOCK congestion control, real-time priority: the QoS of the
  DSP's interrupts), from inside the subscriber callback (``--hold-us``:
  after busy-waiting that long there, as the DSP's step holds its callback;
  ``--hold-key``: set at run time);
* ``can-echo``: a ``udp_multicast`` node (the rig's loop-free bus or python-can's stock one) answering a request frame
  with an 8-byte reply frame (own echoes filtered);
* ``sleep-jitter``: a loop that only sleeps to absolute deadlines at a given
  rate, the floor of the controller's SYNC jitter;
* ``composition``: one lockstep run of :func:`workbench.composition.run_in_process`.

Echo helpers print ``READY <json>`` on stdout once they serve and run until
SIGTERM/SIGINT, then close their session or bus; measurement helpers print
``RESULT <json>`` and exit.
"""

from __future__ import annotations

import argparse
import json
import signal
import socket
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any


def _stop_event() -> threading.Event:
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    return stop


def _say(tag: str, payload: dict[str, Any]) -> None:
    sys.stdout.write(f"{tag} {json.dumps(payload)}\n")
    sys.stdout.flush()


def udp_echo(args: argparse.Namespace) -> int:
    stop = _stop_event()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.settimeout(0.2)
        _say("READY", {"port": sock.getsockname()[1]})
        while not stop.is_set():
            try:
                data, addr = sock.recvfrom(65536)
            except TimeoutError:
                continue
            sock.sendto(data, addr)
    return 0


def zenoh_echo(args: argparse.Namespace) -> int:
    import zenoh

    stop = _stop_event()
    from service_kit.zenoh_log import init_zenoh_log

    init_zenoh_log()
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps([args.listen]))
    if args.tls:
        from service_kit.access import tls_section

        folder = Path(args.tls)
        config.insert_json5("transport/link/tls", json.dumps(tls_section(str(folder / "ca.pem"), str(folder / "echo.pem"), str(folder / "echo.key"))))
    session = zenoh.open(config)
    try:
        pong = session.declare_publisher(args.pong, congestion_control=zenoh.CongestionControl.BLOCK, priority=zenoh.Priority.REAL_TIME, express=True)
        hold = [args.hold_us * 1e-6]

        def echo(sample: Any) -> None:
            payload = sample.payload.to_bytes()
            if hold[0] > 0:  # busy, in zenoh's callback: as the DSP's step holds its callback thread
                until = time.perf_counter() + hold[0]
                while time.perf_counter() < until:
                    pass
            pong.put(payload)

        def set_hold(sample: Any) -> None:
            text = sample.payload.to_string()
            try:
                value = float(text)
            except ValueError:
                return
            if 0.0 <= value <= 1e6:
                hold[0] = value * 1e-6
                session.put(args.hold_key + "/ack", text)

        sub = session.declare_subscriber(args.ping, echo)
        hold_sub = session.declare_subscriber(args.hold_key, set_hold) if args.hold_key else None
        _say("READY", {"listen": args.listen})
        stop.wait()
        if hold_sub is not None:
            hold_sub.undeclare()
        sub.undeclare()
        pong.undeclare()
    finally:
        session.close()
    return 0


def can_echo(args: argparse.Namespace) -> int:
    import can

    stop = _stop_event()
    request = int(args.request_id, 0)
    reply = int(args.reply_id, 0)
    from workbench.bench.pingers import can_bus

    bus = can_bus(args.port, [request], args.channel, loop_free=args.bus == "loop-free")
    try:
        _say("READY", {"port": args.port})
        while not stop.is_set():
            msg = bus.recv(timeout=0.2)
            if msg is None or msg.arbitration_id != request:
                continue
            data = bytes(msg.data[:8]).ljust(8, b"\x00")
            bus.send(can.Message(arbitration_id=reply, data=data, is_extended_id=False))
    finally:
        bus.shutdown()
    return 0


def sleep_jitter(args: argparse.Namespace) -> int:
    """Sleep to absolute deadlines t0 + k/rate exactly as the controller's
    real-time loop does, and record |wake - scheduled|."""
    from service_kit.realtime import apply_realtime
    from workbench.bench.stats import summarize

    # The floor runs under the same real-time measures as the rig it is compared with.
    measures = apply_realtime(args.rt_priority, args.cpu_affinity, whole_process=True, cpu_latency_us=args.cpu_latency_us)
    period = 1.0 / args.rate
    n = max(1, int(round(args.seconds * args.rate)))
    jitter = []
    starts = []
    overruns = 0
    t0 = time.monotonic() + 0.01
    for k in range(n):
        scheduled = t0 + k * period
        delay = scheduled - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        start = time.monotonic()
        starts.append(start)
        jitter.append(abs(start - scheduled))
        if start > scheduled + period:
            overruns += 1
    wall = time.monotonic() - t0
    period_jitter = [abs(b - a - period) for a, b in zip(starts, starts[1:])] or [0.0]
    _say(
        "RESULT",
        {
            "jitter": summarize(jitter),
            "period_jitter": summarize(period_jitter),
            "overruns": overruns,
            "ticks": n,
            "loop_rate_hz": n / wall if wall > 0 else 0.0,
            "realtime": measures.describe(),
        },
    )
    return 0


def composition(args: argparse.Namespace) -> int:
    from workbench import composition as comp

    run = comp.run_in_process(controller={"duration_s": args.sim_s})
    result = run.result
    tet = run.controller.tet.stats()
    _say(
        "RESULT",
        {
            "sim_time_s": result.sim_time_s,
            "wall_time_s": run.wall_time_s,
            "ticks": result.ticks,
            "error": result.error,
            "tet": tet.model_dump(),
        },
    )
    return 0 if result.error is None else 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m workbench.bench.peer", description="helper processes of ralf-hil bench")
    sub = parser.add_subparsers(dest="mode", required=True)
    sub.add_parser("udp-echo", help="bare UDP echo on loopback").set_defaults(func=udp_echo)
    z = sub.add_parser("zenoh-echo", help="zenoh ping -> pong echo")
    z.add_argument("--listen", required=True, help="zenoh endpoint to listen on, e.g. tcp/127.0.0.1:7450")
    z.add_argument("--ping", required=True, help="key expression of pings")
    z.add_argument("--pong", required=True, help="key expression of pongs")
    z.add_argument("--hold-us", type=float, default=0.0, help="busy-wait this long in the callback before answering (the DSP's step)")
    z.add_argument("--hold-key", default="", help="a put of a number (µs) here sets --hold-us; acknowledged on KEY/ack")
    z.add_argument("--tls", default="", metavar="DIR", help="mutual TLS with DIR/ca.pem, DIR/echo.pem and DIR/echo.key (a tls/ endpoint)")
    z.set_defaults(func=zenoh_echo)
    c = sub.add_parser("can-echo", help="udp_multicast request -> reply echo")
    c.add_argument("--channel", default="239.74.163.2")
    c.add_argument("--port", type=int, required=True)
    c.add_argument("--request-id", default="0x080")
    c.add_argument("--reply-id", default="0x181")
    c.add_argument(
        "--bus",
        choices=("loop-free", "stock"),
        default="loop-free",
        help="loop-free: the rig's bus (service_kit/can_udp.py); stock: python-can's udp_multicast",
    )
    c.set_defaults(func=can_echo)
    s = sub.add_parser("sleep-jitter", help="absolute-deadline sleep loop")
    s.add_argument("--rate", type=float, required=True)
    s.add_argument("--seconds", type=float, required=True)
    s.add_argument("--rt-priority", type=int, default=0, help="SCHED_FIFO priority, as the rig's RALF_REALTIME priority (0: normal scheduler)")
    s.add_argument("--cpu-affinity", default="", help="CPUs to pin to, as the rig's RALF_REALTIME cpus")
    s.add_argument("--cpu-latency-us", type=int, default=-1, help="PM QoS CPU wake-up latency bound, as the rig's RALF_REALTIME cpu_latency_us (-1: off)")
    s.set_defaults(func=sleep_jitter)
    p = sub.add_parser("composition", help="one-process lockstep rig run")
    p.add_argument("--sim-s", type=float, required=True)
    p.set_defaults(func=composition)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    raise SystemExit(main())
