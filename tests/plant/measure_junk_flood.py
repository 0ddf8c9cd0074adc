"""A junk-datagram flood against a ticking rig, measured (not a test: run it
inside the loopback-only namespace)::

    .ci/loopback-netns .venv/bin/python -m tests.plant.measure_junk_flood

20,000 undecodable datagrams at 2,000 a second on the CAN group and port for
10 s, while a controller link ticks at 200 Hz (SYNC, TPDO1 within 4 ms,
RPDO1) against the node served by its runner, both on the rig's
udp_multicast bus. Prints the ticks answered, the link's TPDO timeouts, the
node's SYNC watchdog trips and, per end, the datagrams
read and counted (``rx_errors``; ``junk_frames``: skipped by the rig's bus
before decoding) and dropped by the kernel and counted (``kernel_drops``): their sum is the flood plus any real frame the kernel
dropped. ``--runner FILE`` serves the node with the ``run_node`` of another
runner module (e.g. an older one, ``git show REV:plant_emulator/canopen_node/runner.py``);
``--baseline`` sends the same datagrams to the next port, so the rig's bus
sees none: what the host's load and the sender cost the link alone.
The watchdog trips are counted from the first tick to the last (the pause
after the last tick, before the final frame, trips it once more, not counted)."""

from __future__ import annotations

import argparse
import importlib.util
import socket
import threading
import time

import can

from controller.plant_link import PlantLink
from plant_emulator.canopen_node import CanopenNode, NodeConfig, node_can_filters, run_node
from tests.plant.support import FakeApp

GROUP = "239.74.163.2"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--port", type=int, default=48123)
    parser.add_argument("--count", type=int, default=20_000)
    parser.add_argument("--rate", type=float, default=2000.0)
    parser.add_argument("--runner", help="a runner module file whose run_node serves the node")
    parser.add_argument("--baseline", action="store_true", help="send the datagrams to the next port: the sender's cost, no junk on the bus")
    args = parser.parse_args()
    serve = run_node
    if args.runner:
        spec = importlib.util.spec_from_file_location("other_runner", args.runner)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        serve = module.run_node
    node_bus = can.Bus(interface="ralf_udp_multicast", channel=GROUP, port=args.port, can_filters=node_can_filters(1))
    link_bus = can.Bus(interface="ralf_udp_multicast", channel=GROUP, port=args.port)
    node = CanopenNode(FakeApp(), NodeConfig())
    link = PlantLink(link_bus, 1)
    stop = threading.Event()
    server = threading.Thread(target=serve, args=(node_bus, node, stop), daemon=True)
    server.start()
    attacker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    attacker.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 1)
    try:
        link.start_node(timeout=5.0, sample_period_s=0.005)

        def flood() -> None:
            t0 = time.monotonic()
            for k in range(args.count):
                wait = t0 + k / args.rate - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                attacker.sendto(b"\xc1\xc1 junk", (GROUP, target))

        target = args.port + 1 if args.baseline else args.port
        flooder = threading.Thread(target=flood, daemon=True)
        trips_before = node.counters.watchdog_trips
        flooder.start()
        t0 = time.monotonic()
        ticks = answered = 0
        while flooder.is_alive():
            wait = t0 + ticks * 0.005 - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            link.send_sync()
            answered += link.wait_tpdo(0.004) is not None
            link.send_outputs((0.0, 0.0))
            ticks += 1
        trips = node.counters.watchdog_trips - trips_before  # the pause below trips it once more
        time.sleep(0.5)
        link.send_sync()  # a last frame each way carries the kernel's drop count
        link.wait_tpdo(0.5)
        link.take_conflicts()
    finally:
        stop.set()
        server.join(5.0)
        attacker.close()
        node_bus.shutdown()
        link_bus.shutdown()
    c, lc = node.counters, link.counters
    what = f"to port {args.port + 1} (baseline)" if args.baseline else "on the bus"
    print(
        f"{args.count} junk datagrams at {args.rate:.0f}/s {what}; ticks {ticks}, answered {answered}, TPDO timeouts {lc.tpdo_timeouts}, "
        f"node watchdog trips during the ticks {trips}"
    )
    for name, k in (("node", c), ("link", lc)):
        junk, drops = getattr(k, "junk_frames", 0), getattr(k, "kernel_drops", 0)
        print(f"{name}: rx_errors {k.rx_errors} + junk_frames {junk} + kernel_drops {drops} = {k.rx_errors + junk + drops}")


if __name__ == "__main__":
    main()
